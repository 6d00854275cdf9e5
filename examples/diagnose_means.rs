//! Published-means experiments (`diagnose::synth::write_means`): each the
//! mean of 10 perturbed specimens carrying the same effect, one moment
//! magnitude per direction, rotations only, half with `sd_*` columns;
//! diagnosed and scored: confusion matrix, top-1 accuracy, claims on
//! `none`, and the smallest noise any diagnosis used.
//! `cargo run --release --example diagnose_means -- [DEV_DIR] [PER_LABEL] [SEED] [primary]`
use osim_spine::calibrate::experiment::Experiment;
use osim_spine::diagnose::select::{diagnose, Options};
use osim_spine::diagnose::synth;
use std::path::PathBuf;

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
        let o = match diagnose(&exp, &opts) {
            Ok(o) => o,
            Err(e) => {
                // a failed diagnosis counts as a miss and is shown
                println!("means-{i:02} ERR truth={} error: {e}", truth.effect.name());
                rows.push(synth::Scored {
                    truth: truth.effect.name().to_string(),
                    verdict: "error".into(),
                    shrink: 0.0,
                });
                continue;
            }
        };
        let (b, a) = o.heldout_rmse();
        let shrink = if b > 0.0 { 1.0 - a / b } else { 0.0 };
        // the smallest per-cell noise used (class values and stated cells)
        let nm = &o.noise_model;
        let class = [nm.rotation, nm.translation]
            .into_iter()
            .flatten()
            .map(|c| c.sigma);
        let cells = o.sim.cells.iter().filter_map(|c| c.sd);
        let lo = class.chain(cells).fold(f64::INFINITY, f64::min);
        min_noise = min_noise.min(lo);
        let want = truth.effect.name();
        println!(
            "means-{i:02} {} truth={want} verdict={} conf={:.3} shrink={shrink:.2} sd={} {} [{}] {:.1}s | {} | {}",
            if o.verdict == want { "OK " } else { "BAD" },
            o.verdict,
            o.confidence,
            spec.with_sd as u8,
            specimens[*si].0,
            truth.notes,
            t.elapsed().as_secs_f64(),
            osim_spine::diagnose::report::noise_line(&o),
            o.reasons.join("; ")
        );
        rows.push(synth::Scored {
            truth: want.to_string(),
            verdict: o.verdict.to_string(),
            shrink,
        });
    }
    print!("\n{}", synth::score_summary(&rows));
    for sd in [true, false] {
        let sub: Vec<&synth::Scored> = rows
            .iter()
            .zip(&set)
            .filter(|(_, s)| s.1.with_sd == sd)
            .map(|(r, _)| r)
            .collect();
        let ok = sub.iter().filter(|r| r.truth == r.verdict).count();
        println!("with sd_* = {sd}: top-1 {ok}/{}", sub.len());
    }
    println!("smallest noise used by any diagnosis: {min_noise:.4} (deg or mm)");
}
