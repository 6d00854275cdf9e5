//! The chain smoothing's joint model (`generate`, `--smooth chain`): the
//! scoliosis-dev patients were made by scaling each vertebra about its
//! vertebral centre while the joints stayed where the cyclist model has
//! them, so on their exact (clean) sets the landmarks must choose joint
//! centres kept at their offsets from the vertebral centre, and the joint
//! mismatch left must be small; with joint centres scaled with each body
//! it is 2.8 mm cranial-caudal.

mod common;

#[test]
fn scaled_patients_choose_joints_about_the_vertebral_centre() {
    let (Some(generic), Some(geometry), Some(dev)) = (
        common::shared("data/models/cyclistFullBodyMuscle.osim"),
        common::shared("data/geometry-bodyframe"),
        common::shared("scoliosis-dev"),
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let base = tmp.path().join("cyclist");
    common::run_ok(&[
        "base".as_ref(),
        "--generic".as_ref(),
        generic.as_os_str(),
        "--geometry".as_ref(),
        geometry.as_os_str(),
        "--out".as_ref(),
        base.as_os_str(),
    ]);
    for patient in ["D01_thoracic45", "D02_lumbar55", "D03_double"] {
        let out = tmp.path().join(patient).join("p.osim");
        let landmarks = dev.join(patient).join("landmarks_clean.csv");
        common::run_ok(&[
            "generate".as_ref(),
            "--base".as_ref(),
            base.as_os_str(),
            "--landmarks".as_ref(),
            landmarks.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        let report: serde_json::Value = serde_json::from_slice(
            &std::fs::read(tmp.path().join(patient).join("p_report.json")).unwrap(),
        )
        .unwrap();
        let s = &report["smoothing"];
        assert_eq!(s["joint_scaling"], "about_centre", "{patient}: {s}");
        let sd: Vec<f64> = s["joint_sd_mm"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        println!("{patient}: joint mismatch SD {sd:?} mm");
        assert!(
            sd.iter().all(|x| *x < 1.0),
            "{patient}: joint mismatch SD {sd:?} mm"
        );
    }
}
