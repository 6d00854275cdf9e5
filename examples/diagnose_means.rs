//! Published-means experiments (`diagnose::synth::write_means`): each the
//! mean of 10 perturbed specimens carrying the same effect, one moment
//! magnitude per direction, rotations only (with `primary`: only the
//! rotation about each load axis), half with `sd_*` columns; diagnosed and
//! scored: confusion matrix, top-1 accuracy, claims on `none`, the
//! smallest noise any diagnosis used, and per label how often the design
//! sees a gap at all (the baseline's held-out chi-square above the noise,
//! p < 1e-4): an effect whose table the nominal form reproduces within the
//! noise cannot be named by any method.
//! `cargo run --release --example diagnose_means -- [DEV_DIR] [PER_LABEL] [SEED] [primary]`
use osim_spine::calibrate::experiment::Experiment;
use osim_spine::diagnose::select::{diagnose, Options, Outcome, ALPHA};
use osim_spine::diagnose::synth;
use std::path::PathBuf;

/// The smallest per-cell noise a diagnosis used (class values and stated cells).
fn smallest_noise(o: &Outcome) -> f64 {
    let nm = &o.noise_model;
    let class = [nm.rotation, nm.translation]
        .into_iter()
        .flatten()
        .map(|c| c.sigma);
    let cells = o.sim.cells.iter().filter_map(|c| c.sd);
    class.chain(cells).fold(f64::INFINITY, f64::min)
}

/// One line on an outcome.
fn describe(o: &Outcome) -> String {
    let r = &o.remaining;
    let best = osim_spine::diagnose::report::best_candidates(o, 3);
    format!(
        "gap p={:.1e} closed={:.2} red={:.1} misfit={:.2} best=[{}] | {} | {}",
        r.baseline_p_noise,
        r.closed,
        r.reduced_chi2,
        r.misfit(ALPHA),
        best,
        osim_spine::diagnose::report::noise_line(o),
        o.reasons.join("; ")
    )
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dev = PathBuf::from(
        args.get(1)
            .map(String::as_str)
            .unwrap_or("../shared/diagnose-dev"),
    );
    let per: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let seed: u64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(2026);
    let primary = args.get(4).is_some_and(|s| s == "primary");
    // nominal specimens: L1-S1 (dev-13, 5 levels) and T12-S1 (dev-07, 6 levels)
    let specimens = vec![
        ("dev-13".to_string(), vec!["lumbar1".to_string()]),
        ("dev-07".to_string(), vec!["thoracic12".to_string()]),
    ];
    let set = synth::means_set(per, seed, &specimens, primary);
    let tmp = tempfile::tempdir().expect("temp dir");
    let mut rows = Vec::new();
    let mut gaps: Vec<(String, bool)> = Vec::new();
    let mut min_noise = f64::INFINITY;
    for (i, (si, spec)) in set.iter().enumerate() {
        let dir = tmp.path().join(format!("means-{i:02}"));
        let specimen = dev.join(&specimens[*si].0).join("specimen.osim");
        let truth = synth::write_means(&specimen, spec, &dir).expect("generate");
        let t = std::time::Instant::now();
        let exp = Experiment::read(&dir).expect("read");
        let opts = Options {
            progress: false,
            ..Options::default()
        };
        let o = diagnose(&exp, &opts);
        let row = synth::Scored::of(&truth, o.as_ref().ok());
        let want = truth.effect.name();
        let what = match &o {
            Ok(o) => {
                min_noise = min_noise.min(smallest_noise(o));
                gaps.push((want.to_string(), o.remaining.baseline_p_noise < ALPHA));
                describe(o)
            }
            // a failed diagnosis counts as a miss and is shown
            Err(e) => format!("error: {e}"),
        };
        println!(
            "means-{i:02} {} truth={want} verdict={} conf={:.3} shrink={:.2} sd={} {} [{}] {:.1}s {what}",
            if row.hit() { "OK " } else { "BAD" },
            row.verdict.map(|v| v.name()).unwrap_or("error"),
            row.confidence,
            row.shrink,
            spec.with_sd as u8,
            specimens[*si].0,
            truth.notes,
            t.elapsed().as_secs_f64(),
        );
        rows.push(row);
    }
    print!("\n{}", synth::score_summary(&rows));
    for sd in [true, false] {
        let sub: Vec<&synth::Scored> = rows
            .iter()
            .zip(&set)
            .filter(|(_, s)| s.1.with_sd == sd)
            .map(|(r, _)| r)
            .collect();
        let ok = sub.iter().filter(|r| r.hit()).count();
        println!("with sd_* = {sd}: top-1 {ok}/{}", sub.len());
    }
    println!("gap seen by the design (baseline held-out chi-square above the noise, p < 1e-4), per label:");
    let mut labels: Vec<&str> = gaps.iter().map(|g| g.0.as_str()).collect();
    labels.dedup();
    for l in labels {
        let seen = gaps.iter().filter(|g| g.0 == l && g.1).count();
        let n = gaps.iter().filter(|g| g.0 == l).count();
        println!("  {l}: {seen}/{n}");
    }
    println!("smallest noise used by any diagnosis: {min_noise:.4} (deg or mm)");
}
