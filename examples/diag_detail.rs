//! Print every candidate's statistics for one experiment (development aid).
use osim_spine::calibrate::experiment::Experiment;
use osim_spine::diagnose::select::{diagnose, Options};
fn main() {
    let Some(d) = std::env::args().nth(1) else {
        eprintln!("usage: diag_detail EXPERIMENT");
        return;
    };
    let exp = match Experiment::read(&d) {
        Ok(e) => e,
        Err(e) => {
            eprintln!("{e}");
            return;
        }
    };
    let o = match diagnose(
        &exp,
        &Options {
            progress: false,
            ..Options::default()
        },
    ) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{e}");
            return;
        }
    };
    for s in &o.stats {
        println!("{:<22} n={:<3} chi2tr={:>10.1} chi2ho={:>10.1} dtr={:>9.1} dho={:>9.1} p={:.2e} score={:>9.1} it={} earns={}", s.family.label(), s.n_params, s.chi2_train, s.chi2_heldout, s.dchi2_train, s.dchi2_heldout, s.p_train, s.score, s.iterations, s.earns);
        if std::env::args().nth(2).as_deref() == Some(s.family.label()) {
            println!("  {:?}", s.params);
        }
    }
    println!(
        "verdict {} conf {:.3} {}",
        o.verdict,
        o.confidence,
        o.reasons.join("; ")
    );
}
