//! Profiling driver for OpenSim document I/O: repeats one stage of
//! read / parse / write on a model so `perf record` sees only that stage.
//!
//! `cargo run --release --example osim_io_stages -- STAGE N MODEL.osim`
//! with STAGE one of `fsread`, `parse`, `read`, `serialise`, `fswrite` (atomic write
//! of the serialised text), `write`, `rw`,
//! `model`; prints the median time of the N repetitions.

use osim_spine::osim::Document;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (stage, n, path) = match args.as_slice() {
        [_, s, n, p] => (s.as_str(), n.parse::<usize>()?, std::path::PathBuf::from(p)),
        _ => return Err("usage: osim_io_stages STAGE N MODEL.osim".into()),
    };
    let dir = tempfile::tempdir()?;
    let out = dir.path().join("out.osim");
    let text = std::fs::read_to_string(&path)?;
    let doc = Document::parse(&text, &path)?;
    let bytes = doc.to_xml_string();
    let cpu0 = cpu_ticks();
    let mut times = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        match stage {
            "fsread" => drop(std::hint::black_box(std::fs::read(&path)?)),
            "parse" => drop(std::hint::black_box(Document::parse(&text, &path)?)),
            "read" => drop(std::hint::black_box(Document::read(&path)?)),
            "serialise" => drop(std::hint::black_box(doc.to_xml_string())),
            "write" => doc.write(&out)?,
            "fswrite" => osim_spine::util::write_atomic(&out, bytes.as_bytes())?,
            "rw" => Document::read(&path)?.write(&out)?,
            "model" => drop(std::hint::black_box(doc.model()?)),
            other => return Err(format!("unknown stage {other}").into()),
        }
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(|a, b| a.total_cmp(b));
    let cpu = (cpu_ticks() - cpu0) as f64 * 10.0 / n as f64;
    println!(
        "{stage}: median {:.2} ms wall, {cpu:.1} ms CPU (mean) over {n}",
        times[n / 2] * 1e3
    );
    Ok(())
}

/// User + system CPU time of this process in clock ticks (1/100 s on
/// Linux), from /proc/self/stat; 0 elsewhere.
fn cpu_ticks() -> u64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesised command name; utime and stime are the
    // 14th and 15th fields of the whole line.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<u64> = rest
        .split_whitespace()
        .skip(11)
        .take(2)
        .filter_map(|x| x.parse().ok())
        .collect();
    f.iter().sum()
}
