//! The second anatomical template of `check`'s outlier test (LM050),
//! `templates/landmark_layout.csv`, is the default base model's markers,
//! and with it `check` no longer calls the base model's own anatomy an
//! outlier.

mod common;

use osim_spine::generate::base_markers;
use osim_spine::landmarks::check::{base_layout, check_file};
use osim_spine::osim::Document;

/// The embedded layout equals the markers of `base_model/base.osim` (in
/// their bodies' frames), level by level and landmark by landmark.
#[test]
fn layout_is_the_base_models_markers() {
    let doc = Document::read(common::repo_root().join("base_model/base.osim")).unwrap();
    let model = doc.model().unwrap();
    let markers = base_markers(&model).unwrap();
    let layout = base_layout();
    let vertebrae: Vec<_> = markers.keys().filter(|l| !l.is_sacrum()).collect();
    assert_eq!(vertebrae.len(), 17);
    assert_eq!(layout.len(), 17);
    for l in vertebrae {
        let (_, pts) = &markers[l];
        let lay = &layout[l];
        assert_eq!(pts.len(), lay.len(), "{l}");
        for (c, p) in pts {
            let d = (p.coords - lay[c]).norm();
            assert!(d < 1e-12, "{l}_{c}: layout differs by {d} m");
        }
    }
}

/// The README example (the base model posed into a lumbar scoliosis, 1 mm
/// palpation noise, one landmark displaced by 9 mm): the only LM050
/// finding is the planted outlier.
#[test]
fn example_flags_only_its_planted_outlier() {
    let r = check_file(&common::repo_root().join("fixtures/example-scoliosis.csv"));
    let lm050: Vec<String> = r
        .findings
        .iter()
        .filter(|f| f.code == "LM050")
        .flat_map(|f| f.landmarks.clone())
        .collect();
    println!("LM050: {lm050:?}");
    assert_eq!(lm050, vec!["L3_PTL".to_string()], "{:#?}", r.findings);
}
