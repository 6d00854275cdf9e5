//! Run the diagnosis on every labelled development experiment and print
//! the confusion matrix, top-1 accuracy, false claims on `none` cases and
//! the median held-out shrink. `cargo run --release --example diagnose_dev [DIR]`
use osim_spine::calibrate::experiment::Experiment;
use osim_spine::diagnose::select::{diagnose, Options, Verdict};
fn main() {
    let dir = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "../shared/diagnose-dev".into());
    let only = std::env::args().nth(2);
    let mut dirs: Vec<_> = std::fs::read_dir(&dir)
        .expect("dev dir")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.join("truth.toml").exists())
        .collect();
    dirs.sort();
    let mut rows = Vec::new();
    for d in dirs {
        let name = d.file_name().unwrap().to_string_lossy().to_string();
        if let Some(o) = &only {
            if !name.contains(o.as_str()) {
                continue;
            }
        }
        let truth: toml::Value =
            toml::from_str(&std::fs::read_to_string(d.join("truth.toml")).unwrap()).unwrap();
        let truth = truth["effect"].as_str().unwrap().to_string();
        let t = std::time::Instant::now();
        let exp = Experiment::read(&d).unwrap();
        let o = diagnose(
            &exp,
            &Options {
                progress: false,
                ..Options::default()
            },
        )
        .unwrap();
        let (b, a) = o.heldout_rmse();
        let shrink = if b > 0.0 { 1.0 - a / b } else { 0.0 };
        let top: Vec<String> = o
            .ranked
            .iter()
            .take(4)
            .map(|&i| {
                let s = &o.stats[i];
                format!(
                    "{}:{:.0}{}(tr{:.0},ho{:.0})",
                    s.label,
                    s.score,
                    if s.earns { "*" } else { "" },
                    s.dchi2_train,
                    s.dchi2_heldout
                )
            })
            .collect();
        let sc = |k: usize| o.ranked.get(k).map(|&j| o.stats[j].score).unwrap_or(0.0);
        println!("{name} truth={truth} verdict={} conf={:.3} best={:.0} second={:.0} shrink={shrink:.2} [{}] sigma=({}) {:.1}s {}", o.verdict, o.confidence, sc(0), sc(1), top.join(" "), [o.noise_model.rotation, o.noise_model.translation].iter().map(|c| c.map(|c| format!("{:.3}", c.sigma)).unwrap_or_else(|| "-".into())).collect::<Vec<_>>().join(","), t.elapsed().as_secs_f64(), o.reasons.join("; "));
        let left = &o.remaining;
        let effects: Vec<String> = o
            .effects
            .iter()
            .map(|e| format!("{}:{:.2}", e.effect.name(), e.share))
            .collect();
        println!(
            "    effects=[{}] left: closed={:.2} red={:.1} p_struct={:.1e} by={} misfit={:.2} pairs={}",
            effects.join(" "),
            left.closed,
            left.reduced_chi2,
            left.p_structure(),
            left.structure.first().map(|s| format!("{}/{}", s.by, s.cells)).unwrap_or_default(),
            left.misfit(osim_spine::diagnose::select::ALPHA),
            o.pairs
                .iter()
                .map(|p| format!("{}:{:.0}/{:.2}{}", p.fit.family.label(), p.dchi2_heldout, p.win, if p.accepted { "*" } else { "" }))
                .collect::<Vec<_>>()
                .join(" ")
        );
        rows.push(osim_spine::diagnose::synth::Scored {
            truth: Verdict::from_name(&truth).expect("a label of the vocabulary"),
            second: None,
            verdict: Some(o.verdict),
            effects: o.effects.iter().map(|e| e.effect).collect(),
            confidence: o.confidence,
            shrink,
        });
    }
    print!("\n{}", osim_spine::diagnose::synth::score_summary(&rows));
    let extra = rows.iter().filter(|r| r.effects.len() > 1).count();
    println!(
        "experiments with two effects reported: {extra}/{}",
        rows.len()
    );
}
