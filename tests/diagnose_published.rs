//! `diagnose` on real published tables of per-level ranges of motion
//! (`tests/data/published/`, each with the citation and what the table
//! shows by inspection in its `reading.toml`): the verdict names the
//! effects the reading names (never `unidentifiable` where the table shows
//! a level trend), the design predicts whole levels from the others, the
//! noise of a mean of specimens is assumed from the literature and said to
//! be, and the fitted ratios agree with the ratios read off the table
//! (within their 95% intervals).

use osim_spine::calibrate::experiment::Experiment;
use osim_spine::diagnose::noise::NoiseSource;
use osim_spine::diagnose::select::Outcome;
use osim_spine::diagnose::select::{diagnose, Options, Verdict};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The published cases (folders with a `reading.toml`).
fn cases() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/published");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("reading.toml").is_file())
        .collect();
    v.sort();
    v
}

/// One case's reading.
struct Reading {
    effects: Vec<String>,
    ratios: Vec<(String, f64)>,
    trend: bool,
}

fn reading(dir: &Path) -> Reading {
    let t = std::fs::read_to_string(dir.join("reading.toml")).unwrap();
    let v: toml::Value = toml::from_str(&t).unwrap();
    let effects: Vec<String> = v["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e.as_str().unwrap().to_string())
        .collect();
    let ratios = v
        .get("ratio")
        .and_then(|r| r.as_array())
        .map(|a| {
            a.iter()
                .map(|r| {
                    let q = r["quantity"].as_str().unwrap().to_string();
                    (q, r["table"].as_float().unwrap())
                })
                .collect()
        })
        .unwrap_or_default();
    // every case states its source and what the table shows
    for key in ["citation", "where", "reading"] {
        assert!(
            v.get(key)
                .and_then(|x| x.as_str())
                .is_some_and(|s| s.len() > 20),
            "{}: reading.toml needs `{key}`",
            dir.display()
        );
    }
    // and where its numbers can be read
    assert!(
        v.get("source_url")
            .and_then(|x| x.as_str())
            .is_some_and(|s| s.starts_with("https://") && s.len() > 12),
        "{}: reading.toml needs an https `source_url`",
        dir.display()
    );
    Reading {
        trend: effects.iter().any(|e| e == "level_dependent_stiffness"),
        effects,
        ratios,
    }
}

#[test]
fn at_least_three_published_tables_are_shipped() {
    assert!(cases().len() >= 3, "{:?}", cases());
}

#[test]
fn published_tables_get_the_verdict_their_reading_names() {
    for dir in cases() {
        let r = reading(&dir);
        let exp = Experiment::read(&dir).unwrap();
        let o = diagnose(
            &exp,
            &Options {
                progress: false,
                ..Options::default()
            },
        )
        .unwrap();
        let named: Vec<&str> = o.effects.iter().map(|e| e.effect.name()).collect();
        println!(
            "{}: {} {named:?} confidence {:.2}; {:?}; {:?}",
            dir.display(),
            o.verdict,
            o.confidence,
            o.ratios.iter().map(|r| &r.text).collect::<Vec<_>>(),
            o.reasons
        );
        // a table of primary rotations at one magnitude over three or more
        // measured levels: whole levels held out; over fewer, a trend is
        // untestable and the verdict says so
        let levels: BTreeSet<(&str, &str)> = exp
            .rows
            .iter()
            .map(|row| (row.upper.as_str(), row.lower.as_str()))
            .collect();
        assert_eq!(o.design.levels.len(), levels.len());
        if levels.len() >= 3 {
            assert!(o.design.by_level, "{}", o.design.rule);
        } else {
            assert!(!o.design.by_level);
            assert!(o.design.is_untestable("level_dependent_stiffness"));
            assert!(
                o.reasons
                    .iter()
                    .any(|x| x.contains("level_dependent_stiffness")),
                "{:?}",
                o.reasons
            );
        }
        if r.trend {
            assert_ne!(o.verdict, Verdict::Unidentifiable);
        }
        let mut want: Vec<&str> = r.effects.iter().map(String::as_str).collect();
        let mut got = named.clone();
        want.sort_unstable();
        got.sort_unstable();
        assert_eq!(got, want, "{}", dir.display());
        if r.effects.is_empty() {
            assert_eq!(o.verdict, Verdict::None, "{}", dir.display());
        } else {
            assert!(
                matches!(o.verdict, Verdict::Effect(e) if r.effects.iter().any(|w| w == e.name()))
            );
        }
        assert!(o.confidence > 0.0 && o.confidence <= 1.0);
        noise_is_said(&exp, &o);
        // the fitted ratios agree with the table's own
        for (q, table) in &r.ratios {
            let f = o
                .ratios
                .iter()
                .find(|x| &x.quantity == q)
                .unwrap_or_else(|| panic!("{}: no fitted ratio {q}", dir.display()));
            assert!(
                f.ci95[0] <= *table && *table <= f.ci95[1],
                "{}: {q} table {table} outside {}",
                dir.display(),
                f.text
            );
        }
    }
}

/// Means without SDs: the noise is the literature spread, and said to be.
/// With SDs: every cell's noise is its stated SD (in degrees) over the
/// square root of the specimen count, and nothing is assumed about the rotations.
fn noise_is_said(exp: &Experiment, o: &Outcome) {
    let stated = exp
        .rows
        .iter()
        .any(|row| row.sd.iter().any(Option::is_some));
    if !stated {
        assert!(
            o.assumptions.iter().any(|a| a.contains("assumed")),
            "{:?}",
            o.assumptions
        );
        return;
    }
    let n = f64::from(exp.measurement.n_specimens.unwrap());
    for c in &o.sim.cells {
        let sd = exp.rows[c.row].sd[c.dof].unwrap();
        let want = sd.to_degrees() / n.sqrt();
        let got = c.sd.unwrap();
        assert!(
            (got - want).abs() < 1e-9 * want,
            "row {} {got} {want}",
            c.row
        );
    }
    assert!(o
        .noise_model
        .rotation
        .is_some_and(|r| r.source == NoiseSource::Stated));
    assert!(o.assumptions.is_empty(), "{:?}", o.assumptions);
}
