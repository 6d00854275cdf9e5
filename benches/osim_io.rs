//! Read + write speed of the cyclist model (3.3 MB, 520 muscles) next to
//! OpenSim 4.6's `opensim.Model(path)` on the same machine in the same run.
//!
//! `cargo bench --bench osim_io`: criterion groups for parse, typed model
//! and write, then a plain median-of-10 table (read, write, read + write,
//! read + typed model + write) and, in the same run, the median of 10
//! `opensim.Model(path)` with the speed-up ratios (when a Python with
//! `opensim` is found: `$OSIM_SPINE_PYTHON` or `.venv/bin/python`).
//! `benches/osim_io_vs_opensim.py` does the same side by side with the
//! release binary (`osim-spine convert`), one process per run.

use criterion::{criterion_group, Criterion};
use osim_spine::osim::Document;
use std::path::{Path, PathBuf};
use std::time::Instant;

fn cyclist() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/models/cyclistFullBodyMuscle.osim");
    p.exists().then_some(p)
}

fn bench(c: &mut Criterion) {
    let Some(path) = cyclist() else {
        eprintln!("SKIP: ../shared/data/models/cyclistFullBodyMuscle.osim not found");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.osim");
    let mut g = c.benchmark_group("cyclist");
    g.sample_size(10);
    g.bench_function("read (parse + checks)", |b| {
        b.iter(|| Document::read(&path).unwrap())
    });
    let doc = Document::read(&path).unwrap();
    g.bench_function("typed model", |b| b.iter(|| doc.model().unwrap()));
    g.bench_function("write", |b| b.iter(|| doc.write(&out).unwrap()));
    g.finish();
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn opensim_median(path: &Path) -> Option<f64> {
    let py = std::env::var("OSIM_SPINE_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|_| Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python"));
    let script = "import sys,time,opensim\nopensim.Logger.setLevelString('error')\nts=[]\nfor _ in range(10):\n    t=time.perf_counter(); opensim.Model(sys.argv[1]); ts.append(time.perf_counter()-t)\nts.sort(); print(ts[5])";
    let o = std::process::Command::new(py)
        .args(["-c", script, path.to_str()?])
        .output()
        .ok()?;
    String::from_utf8_lossy(&o.stdout).trim().parse().ok()
}

fn table() {
    let Some(path) = cyclist() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.osim");
    let (mut rw, mut rmw, mut r, mut w) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for _ in 0..10 {
        let t = Instant::now();
        let d = Document::read(&path).unwrap();
        d.write(&out).unwrap();
        rw.push(t.elapsed().as_secs_f64());
        drop(d);
        let t = Instant::now();
        let d = Document::read(&path).unwrap();
        d.model().unwrap();
        d.write(&out).unwrap();
        rmw.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let d = Document::read(&path).unwrap();
        r.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        d.write(&out).unwrap();
        w.push(t.elapsed().as_secs_f64());
    }
    let (a, b) = (median(rw), median(rmw));
    println!("\ncyclist model, median of 10 (wall clock):");
    println!(
        "  osim-spine read:                       {:8.1} ms",
        median(r) * 1e3
    );
    println!(
        "  osim-spine write (atomic, fsync):      {:8.1} ms",
        median(w) * 1e3
    );
    println!(
        "  osim-spine read + write:               {:8.1} ms",
        a * 1e3
    );
    println!(
        "  osim-spine read + typed model + write: {:8.1} ms",
        b * 1e3
    );
    match opensim_median(&path) {
        Some(o) => {
            println!(
                "  OpenSim 4.6 opensim.Model(path):       {:8.1} ms",
                o * 1e3
            );
            println!(
                "  speed-up, read + write vs OpenSim load:               {:.1}x",
                o / a
            );
            println!(
                "  speed-up, read + typed model + write vs OpenSim load: {:.1}x",
                o / b
            );
        }
        None => println!("  OpenSim timing skipped (no Python with opensim)"),
    }
}

criterion_group!(benches, bench);

fn main() {
    benches();
    criterion::Criterion::default()
        .configure_from_args()
        .final_summary();
    // The timed table only under `cargo bench` (which passes `--bench`), not
    // in the test mode of `cargo test --all-targets`.
    if std::env::args().any(|a| a == "--bench") {
        table();
    }
}
