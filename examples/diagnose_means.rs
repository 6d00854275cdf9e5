//! Published-means experiments (`diagnose::synth::write_means`): each the
//! mean of 10 perturbed specimens carrying the same effect(s) (a level
//! trend, a shared asymmetry, both, or one of the other effects), one
//! moment magnitude per direction, rotations only (with `primary`: only
//! the rotation about each load axis), half with `sd_*` columns; diagnosed
//! and scored: the published-means reading per kind (`means_summary`),
//! confusion matrix, claims on `none`, the
//! smallest noise any diagnosis used, and per label how often the design
//! sees a gap at all (the baseline's held-out chi-square above the noise,
//! p < 1e-4): an effect whose table the nominal form reproduces within the
//! noise cannot be named by any method.
//!
//! The nominal specimen is the published tables' (`tests/data/published/specimen.osim`,
//! each level's axes the load axes, as a table's rotations about each level's
//! own axes are read), loaded at L1 (5 levels) or T12 (6 levels); a folder of
//! the development set instead uses its lordotic dev-13 (L1-S1) and dev-07
//! (T12-S1) specimens, whose rotations are on the ground axes.
//! `cargo run --release --example diagnose_means -- [SPECIMEN.osim | DEV_DIR] [PER_LABEL] [SEED] [primary]`
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
    let source = PathBuf::from(
        args.get(1)
            .map(String::as_str)
            .unwrap_or("tests/data/published/specimen.osim"),
    );
    let per: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(10);
    let seed: u64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(2026);
    let primary = args.get(4).is_some_and(|s| s == "primary");
    // nominal specimens (path of the .osim) and the bodies loaded
    let specimens: Vec<(String, Vec<String>)> = if source.is_dir() {
        vec![
            (
                source.join("dev-13/specimen.osim").display().to_string(),
                vec!["lumbar1".to_string()],
            ),
            (
                source.join("dev-07/specimen.osim").display().to_string(),
                vec!["thoracic12".to_string()],
            ),
        ]
    } else {
        vec![(
            source.display().to_string(),
            vec!["lumbar1".to_string(), "thoracic12".to_string()],
        )]
    };
    let set = synth::means_set(per, seed, &specimens, primary);
    let tmp = tempfile::tempdir().expect("temp dir");
    // MEANS_KEEP=DIR: write the experiments there (kept) instead of a temp dir
    let keep = std::env::var_os("MEANS_KEEP").map(PathBuf::from);
    let root = keep.as_deref().unwrap_or(tmp.path());
    let mut rows = Vec::new();
    let mut gaps: Vec<(String, bool)> = Vec::new();
    let mut min_noise = f64::INFINITY;
    for (i, (si, spec)) in set.iter().enumerate() {
        let dir = root.join(format!("means-{i:02}"));
        let specimen = PathBuf::from(&specimens[*si].0);
        let truth = synth::write_means(&specimen, spec, &dir).expect("generate");
        let t = std::time::Instant::now();
        let exp = Experiment::read(&dir).expect("read");
        let opts = Options {
            progress: false,
            ..Options::default()
        };
        let o = diagnose(&exp, &opts);
        let row = synth::Scored::of(&truth, o.as_ref().ok());
        let want = match truth.second {
            Some(e) => format!("{}+{}", truth.effect.name(), e.name()),
            None => truth.effect.name().to_string(),
        };
        let what = match &o {
            Ok(o) => {
                min_noise = min_noise.min(smallest_noise(o));
                gaps.push((want.clone(), o.remaining.baseline_p_noise < ALPHA));
                describe(o)
            }
            // a failed diagnosis counts as a miss and is shown
            Err(e) => format!("error: {e}"),
        };
        println!(
            "means-{i:02} {} truth={want} verdict={} effects={} conf={:.3} shrink={:.2} sd={} {} [{}] {:.1}s {what}",
            if row.means_right() { "OK " } else { "BAD" },
            row.verdict.map(|v| v.name()).unwrap_or("error"),
            row.effects.iter().map(|e| e.name()).collect::<Vec<_>>().join("+"),
            row.confidence,
            row.shrink,
            spec.with_sd as u8,
            spec.loaded_body,
            truth.notes,
            t.elapsed().as_secs_f64(),
        );
        rows.push(row);
    }
    print!("\n{}", synth::means_summary(&rows));
    print!("{}", synth::score_summary(&rows));
    for sd in [true, false] {
        let sub: Vec<&synth::Scored> = rows
            .iter()
            .zip(&set)
            .filter(|(_, s)| s.1.with_sd == sd)
            .map(|(r, _)| r)
            .collect();
        let ok = sub.iter().filter(|r| r.means_right()).count();
        println!("with sd_* = {sd}: right {ok}/{}", sub.len());
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
