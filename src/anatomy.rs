//! Anatomy every later stage shares: the vertebral [`Level`]s and the
//! per-level vertebral dimension table (`templates/vertebra_dimensions.csv`,
//! embedded at compile time).
//!
//! The table gives published means and standard deviations (Panjabi et al.
//! 1991 thoracic, 1992 lumbar; Gilad & Nissan 1986 lumbar discs; see the
//! file's header for the citation per column and the `source` column for
//! which values are estimated by rule). Values are stored here in metres.
//!
//! Users: the landmark checks (`landmarks::check`, plausibility ranges), the
//! synthetic landmark generator (`landmarks::synth`) and the procedural base
//! model generator.

use crate::error::{Error, Result};
use crate::util::table::CsvReader;
use std::fmt;
use std::path::Path;
use std::str::FromStr;

/// A vertebral level, cranial to caudal (`T1 < T2 < ... < L5 < S1`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Level {
    /// The first thoracic vertebra.
    T1,
    /// The second thoracic vertebra.
    T2,
    /// The third thoracic vertebra.
    T3,
    /// The fourth thoracic vertebra.
    T4,
    /// The fifth thoracic vertebra.
    T5,
    /// The sixth thoracic vertebra.
    T6,
    /// The seventh thoracic vertebra.
    T7,
    /// The eighth thoracic vertebra.
    T8,
    /// The ninth thoracic vertebra.
    T9,
    /// The tenth thoracic vertebra.
    T10,
    /// The eleventh thoracic vertebra.
    T11,
    /// The twelfth thoracic vertebra.
    T12,
    /// The first lumbar vertebra.
    L1,
    /// The second lumbar vertebra.
    L2,
    /// The third lumbar vertebra.
    L3,
    /// The fourth lumbar vertebra.
    L4,
    /// The fifth lumbar vertebra.
    L5,
    /// The sacrum.
    S1,
}

impl Level {
    /// Every level, cranial to caudal.
    #[rustfmt::skip]
    pub const ALL: [Level; 18] = [
        Level::T1, Level::T2, Level::T3, Level::T4, Level::T5, Level::T6, Level::T7,
        Level::T8, Level::T9, Level::T10, Level::T11, Level::T12,
        Level::L1, Level::L2, Level::L3, Level::L4, Level::L5, Level::S1,
    ];

    /// Position in [`Level::ALL`] (T1 = 0 ... S1 = 17).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Level from its index in [`Level::ALL`].
    pub fn from_index(i: usize) -> Option<Level> {
        Level::ALL.get(i).copied()
    }

    /// The next level caudally (T12 -> L1, L5 -> S1, S1 -> None).
    pub fn caudal(self) -> Option<Level> {
        Level::from_index(self.index() + 1)
    }

    /// The next level cranially (T1 -> None).
    pub fn cranial(self) -> Option<Level> {
        self.index().checked_sub(1).and_then(Level::from_index)
    }

    /// OpenSim body name: `thoracic1`..`thoracic12`, `lumbar1`..`lumbar5`, `sacrum`.
    pub fn body_name(self) -> String {
        let i = self.index();
        match i {
            0..=11 => format!("thoracic{}", i + 1),
            12..=16 => format!("lumbar{}", i - 11),
            _ => "sacrum".to_string(),
        }
    }

    /// Level from an OpenSim body name.
    pub fn from_body_name(name: &str) -> Option<Level> {
        Level::ALL.into_iter().find(|l| l.body_name() == name)
    }

    /// `true` for S1 (the sacrum carries fewer landmarks).
    pub fn is_sacrum(self) -> bool {
        self == Level::S1
    }
}

impl fmt::Display for Level {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let i = self.index();
        match i {
            0..=11 => write!(f, "T{}", i + 1),
            12..=16 => write!(f, "L{}", i - 11),
            _ => write!(f, "S1"),
        }
    }
}

impl FromStr for Level {
    type Err = ();
    /// Parses `T1`..`T12`, `L1`..`L5`, `S1` (case-insensitive).
    fn from_str(s: &str) -> Result<Self, ()> {
        let up = s.trim().to_ascii_uppercase();
        Level::ALL
            .into_iter()
            .find(|l| l.to_string() == up)
            .ok_or(())
    }
}

/// Serialised as its name (`T12`), as in every report.
impl serde::Serialize for Level {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for Level {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(|()| {
            serde::de::Error::custom(format!(
                "'{s}' is not a vertebral level (T1..T12, L1..L5, S1)"
            ))
        })
    }
}

/// Serialise a map keyed by level with its keys in the order of their
/// names (`L1` ... `L5`, `S1`, `T1`, `T10` ...), the order the reports'
/// JSON has always had; use with `#[serde(serialize_with = ...)]`.
pub fn serialize_by_name<V, S>(
    map: &std::collections::BTreeMap<Level, V>,
    s: S,
) -> std::result::Result<S::Ok, S::Error>
where
    V: serde::Serialize,
    S: serde::Serializer,
{
    let mut entries: Vec<(String, &V)> = map.iter().map(|(l, v)| (l.to_string(), v)).collect();
    entries.sort_by(|a, b| a.0.cmp(&b.0));
    s.collect_map(entries)
}

/// Suffix of a bushing's name that its level name drops.
pub const BUSHING_SUFFIX: &str = "_bushing";

/// The level name of a bushing, the one naming rule of intervertebral
/// levels: its name without a trailing `_bushing` (`L5_S1_bushing` ->
/// `L5_S1`), else its name (also when nothing would be left).
pub fn bushing_level_name(bushing: &str) -> &str {
    bushing
        .strip_suffix(BUSHING_SUFFIX)
        .filter(|s| !s.is_empty())
        .unwrap_or(bushing)
}

/// An intervertebral level (motion segment): two adjacent vertebral levels,
/// the cranial one first. Named `<upper>_<lower>` (`T12_L1`), its bushing
/// `<upper>_<lower>_bushing` ([`bushing_level_name`] gives the name back).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct MotionSegment {
    /// The cranial vertebra.
    pub upper: Level,
    /// The caudal vertebra ([`Level::caudal`] of `upper`).
    pub lower: Level,
}

impl MotionSegment {
    /// The segment below `upper` (None for S1).
    pub fn below(upper: Level) -> Option<MotionSegment> {
        Some(MotionSegment {
            upper,
            lower: upper.caudal()?,
        })
    }

    /// The name of its bushing.
    pub fn bushing_name(self) -> String {
        format!("{self}{BUSHING_SUFFIX}")
    }
}

impl fmt::Display for MotionSegment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}_{}", self.upper, self.lower)
    }
}

impl FromStr for MotionSegment {
    type Err = ();
    /// Parses `<upper>_<lower>` of two adjacent levels, cranial first (`T12_L1`, case-insensitive).
    fn from_str(s: &str) -> Result<Self, ()> {
        let (u, l) = s.trim().split_once('_').ok_or(())?;
        let upper: Level = u.parse()?;
        MotionSegment::below(upper)
            .filter(|m| Ok(m.lower) == l.parse())
            .ok_or(())
    }
}

impl serde::Serialize for MotionSegment {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// A bushing of a model and the intervertebral level it stands for: its
/// level name by the one naming rule ([`bushing_level_name`]) and the two
/// bodies it joins, cranial first. The stiffness tables (`personalise`) and
/// the calibration (`calibrate`) name levels with it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BushingLevel {
    /// Level name: the bushing's name without `_bushing` (`L4_L5`).
    pub name: String,
    /// The bushing's name in the model's ForceSet (`L4_L5_bushing`).
    pub bushing: String,
    /// Name of the cranial body (`lumbar4`).
    pub upper_body: String,
    /// Name of the caudal body (`lumbar5`).
    pub lower_body: String,
}

impl BushingLevel {
    /// The level of bushing `bushing` joining `upper_body` (cranial) to
    /// `lower_body`, named by [`bushing_level_name`].
    pub fn new(bushing: &str, upper_body: &str, lower_body: &str) -> BushingLevel {
        BushingLevel {
            name: bushing_level_name(bushing).to_string(),
            bushing: bushing.to_string(),
            upper_body: upper_body.to_string(),
            lower_body: lower_body.to_string(),
        }
    }

    /// The motion segment it belongs to, when its bodies are two adjacent
    /// vertebrae of the model's naming (`lumbar4` over `lumbar5`).
    pub fn segment(&self) -> Option<MotionSegment> {
        let upper = Level::from_body_name(&self.upper_body)?;
        MotionSegment::below(upper)
            .filter(|m| Level::from_body_name(&self.lower_body) == Some(m.lower))
    }
}

/// The embedded CSV text.
pub const EMBEDDED_CSV: &str = include_str!("../templates/vertebra_dimensions.csv");

/// A measured quantity: mean and standard deviation, in metres.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Measure {
    /// Mean (m).
    pub mean: f64,
    /// Standard deviation (m).
    pub sd: f64,
}

impl Measure {
    /// `true` when the source gives no value (stored as 0).
    pub fn is_missing(&self) -> bool {
        self.mean <= 0.0
    }
    /// Range `mean +- k * sd` (sd floored at `floor_frac * mean`).
    pub fn range(&self, k: f64, floor_frac: f64) -> (f64, f64) {
        let sd = self.sd.max(floor_frac * self.mean);
        (self.mean - k * sd, self.mean + k * sd)
    }
}

/// One level's dimensions (metres). See the CSV header for definitions.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LevelDimensions {
    /// The level these dimensions belong to.
    pub level: Level,
    /// Superior endplate width, left-right (m).
    pub sup_ep_width: Measure,
    /// Superior endplate depth, anterior-posterior (m).
    pub sup_ep_depth: Measure,
    /// Inferior endplate width, left-right (m).
    pub inf_ep_width: Measure,
    /// Inferior endplate depth, anterior-posterior (m).
    pub inf_ep_depth: Measure,
    /// Vertebral body height, anterior (m).
    pub ant_height: Measure,
    /// Vertebral body height, posterior (m).
    pub post_height: Measure,
    /// Pedicle height, mean of left and right (m).
    pub pedicle_height: Measure,
    /// Pedicle width, mean of left and right (m).
    pub pedicle_width: Measure,
    /// Spinal canal width, left-right (m).
    pub canal_width: Measure,
    /// Spinal canal depth, anterior-posterior (m).
    pub canal_depth: Measure,
    /// Spinous process length (m).
    pub spinous_length: Measure,
    /// Tip-to-tip width of the transverse processes (m).
    pub transverse_width: Measure,
    /// Height of the disc below this level (0 for S1).
    pub disc_height: Measure,
    /// Provenance string of the row (`P91`, `P92`, `GN86`, `est-...`).
    pub source: String,
}

impl LevelDimensions {
    /// Mean vertebral body height (average of anterior and posterior).
    pub fn body_height(&self) -> Measure {
        Measure {
            mean: 0.5 * (self.ant_height.mean + self.post_height.mean),
            sd: 0.5 * (self.ant_height.sd + self.post_height.sd),
        }
    }
}

/// The dimension table: one row per level, cranial to caudal.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DimensionTable {
    rows: Vec<LevelDimensions>,
}

const COLUMNS: [&str; 13] = [
    "sup_ep_width",
    "sup_ep_depth",
    "inf_ep_width",
    "inf_ep_depth",
    "ant_height",
    "post_height",
    "pedicle_height",
    "pedicle_width",
    "canal_width",
    "canal_depth",
    "spinous_length",
    "transverse_width",
    "disc_height",
];

impl DimensionTable {
    /// The table shipped with the crate. Parsing it cannot fail at run time
    /// for a released build (a unit test parses it), but the error path is
    /// kept rather than a panic.
    pub fn embedded() -> Result<Self> {
        Self::parse(EMBEDDED_CSV, Path::new("templates/vertebra_dimensions.csv"))
    }

    /// Parse a table in the same format (millimetres), e.g. a user's own.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let mut header: Option<Vec<String>> = None;
        let mut rows = Vec::new();
        for rec in CsvReader::new(text, path).records() {
            let rec = rec?;
            let line_no = rec.line();
            let fields: Vec<&str> = rec.cells().collect();
            let Some(h) = &header else {
                header = Some(fields.iter().map(|s| s.to_string()).collect());
                continue;
            };
            if fields.len() != h.len() {
                return Err(Error::parse(
                    path,
                    format!("line {line_no}"),
                    format!("expected {} fields, found {}", h.len(), fields.len()),
                ));
            }
            let get = |name: &str| -> Result<&str> {
                h.iter()
                    .position(|c| c == name)
                    .and_then(|k| fields.get(k).copied())
                    .ok_or_else(|| Error::parse(path, "header", format!("missing column `{name}`")))
            };
            let num = |name: &str| -> Result<f64> {
                let s = get(name)?;
                let v: f64 = s.parse().map_err(|_| {
                    Error::parse(
                        path,
                        format!("line {line_no}"),
                        format!("column `{name}`: expected a number, found `{s}`"),
                    )
                })?;
                if !v.is_finite() || v < 0.0 {
                    return Err(Error::parse(
                        path,
                        format!("line {line_no}"),
                        format!("column `{name}`: expected a finite value >= 0, found {v}"),
                    ));
                }
                Ok(v * 1e-3)
            };
            let measure = |name: &str| -> Result<Measure> {
                Ok(Measure {
                    mean: num(name)?,
                    sd: num(&format!("{name}_sd"))?,
                })
            };
            let level_s = get("level")?;
            let level: Level = level_s.parse().map_err(|_| {
                Error::parse(
                    path,
                    format!("line {line_no}"),
                    format!("unknown level `{level_s}` (expected T1..T12, L1..L5, S1)"),
                )
            })?;
            let m: Vec<Measure> = COLUMNS.iter().map(|c| measure(c)).collect::<Result<_>>()?;
            rows.push(LevelDimensions {
                level,
                sup_ep_width: m[0],
                sup_ep_depth: m[1],
                inf_ep_width: m[2],
                inf_ep_depth: m[3],
                ant_height: m[4],
                post_height: m[5],
                pedicle_height: m[6],
                pedicle_width: m[7],
                canal_width: m[8],
                canal_depth: m[9],
                spinous_length: m[10],
                transverse_width: m[11],
                disc_height: m[12],
                source: get("source")?.to_string(),
            });
        }
        rows.sort_by_key(|r| r.level);
        for w in rows.windows(2) {
            if w[0].level == w[1].level {
                return Err(Error::parse(
                    path,
                    "rows",
                    format!("level {} appears twice", w[0].level),
                ));
            }
        }
        for l in Level::ALL {
            if !rows.iter().any(|r| r.level == l) {
                return Err(Error::parse(
                    path,
                    "rows",
                    format!("level {l} missing (the table needs T1..L5 and S1)"),
                ));
            }
        }
        Ok(DimensionTable { rows })
    }

    /// Dimensions of one level.
    pub fn level(&self, level: Level) -> &LevelDimensions {
        // parse() guarantees every level is present exactly once, sorted.
        &self.rows[level.index()]
    }

    /// All rows, cranial to caudal.
    pub fn rows(&self) -> &[LevelDimensions] {
        &self.rows
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_table_with_bom_crlf_and_quotes_reads_as_the_embedded_one() {
        let want = DimensionTable::embedded().unwrap();
        let path = Path::new("dims.csv");
        let lines: Vec<String> = EMBEDDED_CSV.lines().map(String::from).collect();
        let first = lines.iter().position(|l| l.starts_with("level")).unwrap() + 1;
        // the first row with its first two cells quoted (one with blanks around)
        let quoted = |row: usize, cell: usize, new: &str| {
            let mut v = lines.clone();
            let mut cells: Vec<String> = v[row].split(',').map(String::from).collect();
            cells[cell] = new.replace('@', &cells[cell]);
            v[row] = cells.join(",");
            v
        };
        let mut v = quoted(first, 0, "\"@\"");
        v[first] = v[first].replacen(',', ", \"", 1);
        let (head, tail) = v[first].split_once(", \"").unwrap();
        v[first] = format!("{head}, \"{}", tail.replacen(',', "\" ,", 1));
        let text = format!("\u{feff}{}\r\n", v.join("\r\n"));
        assert!(text.contains("\"T1\", \""), "{}", &v[first]);
        assert_eq!(DimensionTable::parse(&text, path).unwrap(), want);
        // a quoted comma is one cell: the row keeps its width and the cell
        // is refused as a number, on the file's line
        let bad = quoted(first + 2, 1, "\"@,5\"");
        let e = DimensionTable::parse(&bad.join("\r\n"), path)
            .unwrap_err()
            .to_string();
        let cell = lines[first + 2].split(',').nth(1).unwrap().to_string();
        let line = first + 3;
        assert!(
            e.contains(&format!(
                "dims.csv: line {line}: column `sup_ep_width`: expected a number, found `{cell},5`"
            )),
            "{e}"
        );
    }

    #[test]
    fn embedded_table_parses_and_is_anatomically_ordered() {
        let t = DimensionTable::embedded().unwrap();
        assert_eq!(t.rows().len(), 18);
        // Published trend: endplates widen and bodies grow caudally T1 -> L4.
        for w in t.rows()[..16].windows(2) {
            assert!(
                w[1].sup_ep_width.mean >= w[0].sup_ep_width.mean,
                "{:?}",
                w[1].level
            );
            assert!(w[1].sup_ep_depth.mean >= w[0].sup_ep_depth.mean - 1e-3);
        }
        let l3 = t.level(Level::L3);
        assert!(l3.sup_ep_width.mean > 0.03 && l3.sup_ep_width.mean < 0.06);
        assert!(t.level(Level::S1).ant_height.is_missing());
    }

    #[test]
    fn malformed_table_is_rejected_with_line() {
        let bad = "level,x\nT1,1\n";
        let e = DimensionTable::parse(bad, Path::new("t.csv")).unwrap_err();
        assert!(e.to_string().contains("t.csv"), "{e}");
        let text = EMBEDDED_CSV.replace("T5,28.5", "T5,abc");
        let e = DimensionTable::parse(&text, Path::new("t.csv")).unwrap_err();
        assert!(e.to_string().contains("expected a number"), "{e}");
    }

    #[test]
    fn level_serialises_as_its_name_and_back() {
        for l in Level::ALL {
            let json = serde_json::to_string(&l).unwrap();
            assert_eq!(json, format!("\"{l}\""));
            assert_eq!(serde_json::from_str::<Level>(&json).unwrap(), l);
        }
        assert!(serde_json::from_str::<Level>("\"pelvis\"").is_err());
    }

    #[test]
    fn motion_segments_follow_the_bushing_naming_rule() {
        let m: MotionSegment = "t12_L1".parse().unwrap();
        assert_eq!((m.upper, m.lower), (Level::T12, Level::L1));
        assert_eq!(m.to_string(), "T12_L1");
        assert_eq!(m.bushing_name(), "T12_L1_bushing");
        assert_eq!(bushing_level_name(&m.bushing_name()), "T12_L1");
        assert_eq!(bushing_level_name("_bushing"), "_bushing");
        assert_eq!(bushing_level_name("disc"), "disc");
        // not adjacent, caudal first, S1 has no segment below
        for bad in ["T11_L1", "L1_T12", "S1_S2", "L5", "L5_S1_x"] {
            assert!(bad.parse::<MotionSegment>().is_err(), "{bad}");
        }
        assert_eq!(MotionSegment::below(Level::S1), None);
        assert_eq!(
            serde_json::to_string(&MotionSegment::below(Level::L5).unwrap()).unwrap(),
            "\"L5_S1\""
        );
    }

    #[test]
    fn a_bushing_level_is_named_by_the_rule_and_knows_its_segment() {
        let l = BushingLevel::new("L4_L5_bushing", "lumbar4", "lumbar5");
        assert_eq!(
            (l.name.as_str(), l.bushing.as_str()),
            ("L4_L5", "L4_L5_bushing")
        );
        assert_eq!(l.segment(), "L4_L5".parse().ok());
        // the segment comes from the bodies, not from the bushing's name
        let odd = BushingLevel::new("disc", "thoracic12", "lumbar1");
        assert_eq!(
            (odd.name.as_str(), odd.segment()),
            ("disc", MotionSegment::below(Level::T12))
        );
        // bodies caudal first, not adjacent, or not vertebrae: no segment
        for (u, w) in [
            ("lumbar5", "lumbar4"),
            ("lumbar3", "lumbar5"),
            ("torso", "lumbar1"),
        ] {
            assert_eq!(BushingLevel::new("b", u, w).segment(), None, "{u} {w}");
        }
    }
}
