//! Text put into messages: a name or cell shown as the user could type it
//! back (invisible and control characters escaped, long fields cut), and
//! lists of findings of one kind kept to a few lines.

/// Longest field echoed in a message (characters); longer ones are cut.
pub const MAX_SHOWN_CHARS: usize = 80;

/// `s` for a message: characters a terminal would not show (controls,
/// zero-width and other format characters, a byte-order mark) written as
/// `\u{...}` escapes, and cut after [`MAX_SHOWN_CHARS`] characters with the
/// total length said.
pub fn shown(s: &str) -> String {
    let mut out = String::new();
    let n = s.chars().count();
    for c in s.chars().take(MAX_SHOWN_CHARS) {
        if invisible(c) {
            out.push_str(&format!("\\u{{{:04X}}}", c as u32));
        } else {
            out.push(c);
        }
    }
    if n > MAX_SHOWN_CHARS {
        out.push_str(&format!("... ({n} characters)"));
    }
    out
}

/// A character that prints as nothing (or moves the cursor).
fn invisible(c: char) -> bool {
    c.is_control()
        || matches!(c,
            '\u{00AD}' | '\u{034F}' | '\u{061C}' | '\u{115F}' | '\u{1160}' | '\u{17B4}' | '\u{17B5}'
            | '\u{180B}'..='\u{180F}' | '\u{200B}'..='\u{200F}' | '\u{202A}'..='\u{202E}'
            | '\u{2060}'..='\u{206F}' | '\u{3164}' | '\u{FE00}'..='\u{FE0F}' | '\u{FEFF}'
            | '\u{FFA0}' | '\u{FFF0}'..='\u{FFFB}')
}

/// The first `n` of `items`, comma separated, then "... and K more like
/// this" for the rest.
pub fn bounded_list(items: &[String], n: usize) -> String {
    let mut s = items[..items.len().min(n)].join(", ");
    if items.len() > n {
        s.push_str(&format!(" ... and {} more like this", items.len() - n));
    }
    s
}

/// `items` written one after another with `sep` between them (a list of
/// levels or segments in a console line).
pub fn joined<T: std::fmt::Display>(items: &[T], sep: &str) -> String {
    let mut s = String::new();
    for (i, x) in items.iter().enumerate() {
        if i > 0 {
            s.push_str(sep);
        }
        s.push_str(&x.to_string());
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invisible_characters_are_escaped_and_long_fields_cut() {
        assert_eq!(shown("L3_\u{200B}SEC"), "L3_\\u{200B}SEC");
        assert_eq!(shown("a\0b\u{FEFF}"), "a\\u{0000}b\\u{FEFF}");
        assert_eq!(shown("L3_SEC"), "L3_SEC");
        let long = "x".repeat(10_000_000);
        let s = shown(&long);
        assert!(s.len() < 120 && s.ends_with("(10000000 characters)"), "{s}");
    }

    #[test]
    fn lists_are_bounded() {
        let items: Vec<String> = (0..5000).map(|i| format!("f{i}")).collect();
        assert_eq!(
            bounded_list(&items, 2),
            "f0, f1 ... and 4998 more like this"
        );
        assert_eq!(bounded_list(&items[..2], 5), "f0, f1");
    }
}
