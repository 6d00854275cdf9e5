//! Label tables of NIfTI label maps: which integer label is which level.
//!
//! Built in (every class by name, so that a label can be named in messages
//! and a label a table does not have is evidence against it):
//! - TotalSegmentator v1, 104 classes (`totalsegmentator/map_to_binary.py`,
//!   `class_map["total_v1"]` in github.com/wasserth/TotalSegmentator):
//!   18..34 `vertebrae_L5`..`vertebrae_T1`, 35..41 `vertebrae_C7`..
//!   `vertebrae_C1`, 92 `sacrum`;
//! - TotalSegmentator v2, task `total`, 117 classes (`class_map["total"]`):
//!   25 `sacrum`, 26 `vertebrae_S1`, 27..43 `vertebrae_L5`..`vertebrae_T1`,
//!   44..50 `vertebrae_C7`..`vertebrae_C1`; every other label is an organ,
//!   a vessel or another bone.
//! - TotalSpineSeg (README "List of classes",
//!   `totalspineseg/resources/labels_maps/tss_map.json` in
//!   github.com/neuropoly/totalspineseg): 1 spinal cord, 2 spinal canal,
//!   11..17 C1..C7, 21..32 T1..T12, 41..45 L1..L5, 50 sacrum, 63..100 discs.
//!
//! Any other table: `--labels FILE`, one `LABEL NAME` pair a line
//! (separated by a comma, a colon, `=` or white space; `#` starts a
//! comment), NAME a level (`L3`, `vertebrae_L3`, `S1`, `sacrum`) or any
//! other structure name (kept so that it can be named as "not a vertebra").

use crate::error::{Error, Result};
use crate::landmarks::Level;
use std::collections::BTreeMap;
use std::path::Path;

/// What one label of a map stands for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LabelClass {
    /// A vertebra of the T1..S1 chain (S1 = the sacrum).
    Level(Level),
    /// A cervical vertebra (C1..C7): a vertebra, but outside the model.
    Cervical(u8),
    /// Anything else (organ, disc, cord, other bone), by name.
    Other(String),
}

/// Which table a label map was read with.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelTable {
    /// Name for reports (`TotalSegmentator (total)`, `TotalSpineSeg`, a file).
    pub name: String,
    /// Label -> class.
    pub classes: BTreeMap<u32, LabelClass>,
}

/// Level named by a structure name: `L3`, `vertebrae_L3`, `vertebra L3`,
/// `S1`, `vertebrae_S1`, `sacrum` (case-insensitive); `None` otherwise.
pub(crate) fn level_from_name(name: &str) -> Option<Level> {
    let n = name.trim().to_ascii_lowercase();
    if n == "sacrum" || n == "s" {
        return Some(Level::S1);
    }
    let bare = n
        .strip_prefix("vertebrae_")
        .or_else(|| n.strip_prefix("vertebra_"))
        .or_else(|| n.strip_prefix("vertebrae "))
        .or_else(|| n.strip_prefix("vertebra "))
        .unwrap_or(&n);
    bare.parse().ok()
}

/// Cervical vertebra number of a name (`C4`, `vertebrae_C4`).
fn cervical_from_name(name: &str) -> Option<u8> {
    let n = name.trim().to_ascii_lowercase();
    let bare = n.strip_prefix("vertebrae_").unwrap_or(&n);
    let k: u8 = bare.strip_prefix('c')?.parse().ok()?;
    (1..=7).contains(&k).then_some(k)
}

/// Class of a structure name.
pub fn class_of_name(name: &str) -> LabelClass {
    if let Some(l) = level_from_name(name) {
        LabelClass::Level(l)
    } else if let Some(c) = cervical_from_name(name) {
        LabelClass::Cervical(c)
    } else {
        LabelClass::Other(name.trim().to_string())
    }
}

const TOTAL_V1_NAMES: &str = concat!(
    "spleen kidney_right kidney_left gallbladder liver stomach aorta inferior_vena_cava ",
    "portal_vein_and_splenic_vein pancreas adrenal_gland_right adrenal_gland_left ",
    "lung_upper_lobe_left lung_lower_lobe_left lung_upper_lobe_right lung_middle_lobe_right ",
    "lung_lower_lobe_right vertebrae_L5 vertebrae_L4 vertebrae_L3 vertebrae_L2 vertebrae_L1 ",
    "vertebrae_T12 vertebrae_T11 vertebrae_T10 vertebrae_T9 vertebrae_T8 vertebrae_T7 ",
    "vertebrae_T6 vertebrae_T5 vertebrae_T4 vertebrae_T3 vertebrae_T2 vertebrae_T1 vertebrae_C7 ",
    "vertebrae_C6 vertebrae_C5 vertebrae_C4 vertebrae_C3 vertebrae_C2 vertebrae_C1 esophagus ",
    "trachea heart_myocardium heart_atrium_left heart_ventricle_left heart_atrium_right ",
    "heart_ventricle_right pulmonary_artery brain iliac_artery_left iliac_artery_right ",
    "iliac_vena_left iliac_vena_right small_bowel duodenum colon rib_left_1 rib_left_2 rib_left_3 ",
    "rib_left_4 rib_left_5 rib_left_6 rib_left_7 rib_left_8 rib_left_9 rib_left_10 rib_left_11 ",
    "rib_left_12 rib_right_1 rib_right_2 rib_right_3 rib_right_4 rib_right_5 rib_right_6 ",
    "rib_right_7 rib_right_8 rib_right_9 rib_right_10 rib_right_11 rib_right_12 humerus_left ",
    "humerus_right scapula_left scapula_right clavicula_left clavicula_right femur_left ",
    "femur_right hip_left hip_right sacrum face gluteus_maximus_left gluteus_maximus_right ",
    "gluteus_medius_left gluteus_medius_right gluteus_minimus_left gluteus_minimus_right ",
    "autochthon_left autochthon_right iliopsoas_left iliopsoas_right urinary_bladder",
);

const TOTAL_V2_NAMES: &str = concat!(
    "spleen kidney_right kidney_left gallbladder liver stomach pancreas adrenal_gland_right ",
    "adrenal_gland_left lung_upper_lobe_left lung_lower_lobe_left lung_upper_lobe_right ",
    "lung_middle_lobe_right lung_lower_lobe_right esophagus trachea thyroid_gland small_bowel ",
    "duodenum colon urinary_bladder prostate kidney_cyst_left kidney_cyst_right sacrum ",
    "vertebrae_S1 vertebrae_L5 vertebrae_L4 vertebrae_L3 vertebrae_L2 vertebrae_L1 vertebrae_T12 ",
    "vertebrae_T11 vertebrae_T10 vertebrae_T9 vertebrae_T8 vertebrae_T7 vertebrae_T6 vertebrae_T5 ",
    "vertebrae_T4 vertebrae_T3 vertebrae_T2 vertebrae_T1 vertebrae_C7 vertebrae_C6 vertebrae_C5 ",
    "vertebrae_C4 vertebrae_C3 vertebrae_C2 vertebrae_C1 heart aorta pulmonary_vein ",
    "brachiocephalic_trunk subclavian_artery_right subclavian_artery_left ",
    "common_carotid_artery_right common_carotid_artery_left brachiocephalic_vein_left ",
    "brachiocephalic_vein_right atrial_appendage_left superior_vena_cava inferior_vena_cava ",
    "portal_vein_and_splenic_vein iliac_artery_left iliac_artery_right iliac_vena_left ",
    "iliac_vena_right humerus_left humerus_right scapula_left scapula_right clavicula_left ",
    "clavicula_right femur_left femur_right hip_left hip_right spinal_cord gluteus_maximus_left ",
    "gluteus_maximus_right gluteus_medius_left gluteus_medius_right gluteus_minimus_left ",
    "gluteus_minimus_right autochthon_left autochthon_right iliopsoas_left iliopsoas_right brain ",
    "skull rib_left_1 rib_left_2 rib_left_3 rib_left_4 rib_left_5 rib_left_6 rib_left_7 ",
    "rib_left_8 rib_left_9 rib_left_10 rib_left_11 rib_left_12 rib_right_1 rib_right_2 ",
    "rib_right_3 rib_right_4 rib_right_5 rib_right_6 rib_right_7 rib_right_8 rib_right_9 ",
    "rib_right_10 rib_right_11 rib_right_12 sternum costal_cartilages",
);

/// A table from its class names, label 1 first.
fn from_names(name: &str, names: &str) -> LabelTable {
    let classes = names
        .split_whitespace()
        .enumerate()
        .map(|(i, n)| (i as u32 + 1, class_of_name(n)))
        .collect();
    LabelTable {
        name: name.into(),
        classes,
    }
}

impl LabelTable {
    /// TotalSegmentator v1 (104 classes).
    pub fn total_segmentator_v1() -> LabelTable {
        from_names("TotalSegmentator v1 (104 classes)", TOTAL_V1_NAMES)
    }

    /// TotalSegmentator v2, task `total` (117 classes).
    pub fn total_segmentator() -> LabelTable {
        from_names("TotalSegmentator v2 (total, 117 classes)", TOTAL_V2_NAMES)
    }

    /// TotalSpineSeg (vertebrae, sacrum, cord, canal, discs).
    pub(crate) fn total_spine_seg() -> LabelTable {
        let mut classes = BTreeMap::new();
        classes.insert(1, LabelClass::Other("spinal_cord".into()));
        classes.insert(2, LabelClass::Other("spinal_canal".into()));
        for c in 1..=7u8 {
            classes.insert(10 + c as u32, LabelClass::Cervical(c));
        }
        for i in 0..12 {
            classes.insert(21 + i as u32, LabelClass::Level(Level::ALL[i]));
        }
        for i in 0..5 {
            classes.insert(41 + i as u32, LabelClass::Level(Level::ALL[12 + i]));
        }
        classes.insert(50, LabelClass::Level(Level::S1));
        for d in [
            63, 64, 65, 66, 67, 71, 72, 73, 74, 75, 76, 77, 78, 79, 80, 81, 82,
        ] {
            classes.insert(d, LabelClass::Other("disc".into()));
        }
        for d in [91, 92, 93, 94, 95, 100] {
            classes.insert(d, LabelClass::Other("disc".into()));
        }
        LabelTable {
            name: "TotalSpineSeg".into(),
            classes,
        }
    }

    /// The built-in tables.
    pub fn builtin() -> Vec<LabelTable> {
        vec![
            LabelTable::total_segmentator_v1(),
            LabelTable::total_segmentator(),
            LabelTable::total_spine_seg(),
        ]
    }

    /// The name of a label's class (`vertebrae_L3`, `liver`), `None` when
    /// the table has no such label.
    pub fn class_name(&self, label: u32) -> Option<String> {
        self.classes.get(&label).map(|c| match c {
            LabelClass::Level(l) if l.is_sacrum() => "sacrum".to_string(),
            LabelClass::Level(l) => format!("vertebra {l}"),
            LabelClass::Cervical(c) => format!("vertebra C{c}"),
            LabelClass::Other(n) => n.clone(),
        })
    }

    /// Read a `--labels` file.
    pub fn read(path: &Path) -> Result<LabelTable> {
        let text = crate::util::read_text_capped(path, 1 << 20, "label tables")?;
        let table = LabelTable::parse(&text, path)?;
        Ok(table)
    }

    /// Parse the text of a `--labels` file (`path` for messages).
    pub fn parse(text: &str, path: &Path) -> Result<LabelTable> {
        let mut classes = BTreeMap::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let (num, name) = split_pair(line).ok_or_else(|| {
                Error::parse(
                    path,
                    format!("line {}", i + 1),
                    "expected `LABEL NAME` (e.g. `27 vertebrae_L5` or `27,L5`)",
                )
            })?;
            let label: u32 = num.parse().map_err(|_| {
                Error::parse(
                    path,
                    format!("line {}", i + 1),
                    format!("label '{num}' is not a non-negative integer"),
                )
            })?;
            if classes.insert(label, class_of_name(name)).is_some() {
                return Err(Error::parse(
                    path,
                    format!("line {}", i + 1),
                    format!("label {label} is given twice"),
                ));
            }
        }
        if !classes.values().any(|c| matches!(c, LabelClass::Level(_))) {
            return Err(Error::invalid(
                path.display().to_string(),
                "the label table names no vertebra of T1..L5 or the sacrum",
            ));
        }
        Ok(LabelTable {
            name: path.display().to_string(),
            classes,
        })
    }

    /// Labels of each level (TotalSegmentator has two for S1).
    pub fn labels_of_levels(&self) -> BTreeMap<Level, Vec<u32>> {
        let mut out: BTreeMap<Level, Vec<u32>> = BTreeMap::new();
        for (&label, class) in &self.classes {
            if let LabelClass::Level(l) = class {
                out.entry(*l).or_default().push(label);
            }
        }
        out
    }
}

/// `LABEL NAME` split at the first separator.
fn split_pair(line: &str) -> Option<(&str, &str)> {
    let at = line.find(|c: char| c == ',' || c == ':' || c == '=' || c.is_whitespace())?;
    let (a, b) = line.split_at(at);
    let b =
        b[1..].trim_start_matches(|c: char| c == ',' || c == ':' || c == '=' || c.is_whitespace());
    let b = b.trim().trim_matches('"');
    (!a.trim().is_empty() && !b.is_empty()).then_some((a.trim(), b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_tables_cover_t1_to_sacrum() {
        for t in LabelTable::builtin() {
            let levels = t.labels_of_levels();
            assert_eq!(levels.len(), 18, "{}", t.name);
        }
        // TotalSegmentator's own class maps (map_to_binary.py).
        let v1 = LabelTable::total_segmentator_v1();
        assert_eq!(v1.classes.len(), 104);
        assert_eq!(v1.classes[&18], LabelClass::Level(Level::L5));
        assert_eq!(v1.classes[&34], LabelClass::Level(Level::T1));
        assert_eq!(v1.classes[&35], LabelClass::Cervical(7));
        assert_eq!(v1.classes[&92], LabelClass::Level(Level::S1));
        assert_eq!(v1.classes[&7], LabelClass::Other("aorta".into()));
        let ts = LabelTable::total_segmentator();
        assert_eq!(ts.classes.len(), 117);
        assert_eq!(ts.classes[&25], LabelClass::Level(Level::S1));
        assert_eq!(ts.classes[&26], LabelClass::Level(Level::S1));
        assert_eq!(ts.classes[&79], LabelClass::Other("spinal_cord".into()));
        assert_eq!(
            ts.classes[&117],
            LabelClass::Other("costal_cartilages".into())
        );
        assert_eq!(ts.classes[&27], LabelClass::Level(Level::L5));
        assert_eq!(ts.classes[&43], LabelClass::Level(Level::T1));
        assert_eq!(ts.classes[&44], LabelClass::Cervical(7));
        let tss = LabelTable::total_spine_seg();
        assert_eq!(tss.classes[&21], LabelClass::Level(Level::T1));
        assert_eq!(tss.classes[&32], LabelClass::Level(Level::T12));
        assert_eq!(tss.classes[&45], LabelClass::Level(Level::L5));
    }

    #[test]
    fn names_and_files() {
        assert_eq!(level_from_name("vertebrae_L3"), Some(Level::L3));
        assert_eq!(level_from_name("Sacrum"), Some(Level::S1));
        assert_eq!(level_from_name("liver"), None);
        let t =
            LabelTable::parse("# mine\n7, L2\n8 liver\n9=vertebrae_S1\n", Path::new("t")).unwrap();
        assert_eq!(t.classes[&7], LabelClass::Level(Level::L2));
        assert_eq!(t.classes[&8], LabelClass::Other("liver".into()));
        assert_eq!(t.classes[&9], LabelClass::Level(Level::S1));
        assert!(LabelTable::parse("x L2\n", Path::new("t")).is_err());
        assert!(LabelTable::parse("1 L2\n1 L3\n", Path::new("t")).is_err());
        assert!(LabelTable::parse("1 liver\n", Path::new("t")).is_err());
    }
}
