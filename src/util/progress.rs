//! The crate's one progress bar: every long run (surfaces of a label map,
//! calibration starts, sensitivity samples, variability models, diagnosis
//! fits, flexibility film fits, dynamic steps) shows the same line on stderr,
//! `<what> [bar] done/total <unit> (eta) <message>`, and nothing when it is
//! not wanted (indicatif hides it when stderr is not a terminal).

use indicatif::{ProgressBar, ProgressStyle};

/// The bar every long run reports to (an `indicatif` bar).
pub type Bar = ProgressBar;

/// A bar of `len` steps of `unit` (e.g. `fits`, `steps`), labelled `what`;
/// hidden when `show` is false.
pub fn bar(what: &str, len: u64, unit: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let escape = |s: &str| s.replace('{', "{{").replace('}', "}}");
    let (what, unit) = (escape(what), escape(unit));
    let template = format!("{what} [{{bar:30}}] {{pos}}/{{len}} {unit} ({{eta}}) {{msg}}");
    let b = ProgressBar::new(len);
    if let Ok(style) = ProgressStyle::with_template(&template) {
        b.set_style(style);
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_label_with_braces_does_not_break_the_template() {
        // A label is the user's text (a case name): braces in it must not
        // be read as template keys nor make the bar fail.
        let b = bar("case {x}", 3, "steps", true);
        b.inc(1);
        assert_eq!(b.position(), 1);
        assert!(bar("x", 3, "steps", false).is_hidden());
    }
}
