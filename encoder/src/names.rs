//! Names that come from files (a material's channel names, its SOURCE_MAPS file names) made safe
//! to print on a terminal and to use as file names. A file may set them to anything: control
//! characters and terminal escapes, path separators, `..`, a NUL, bidirectional overrides that
//! make text read differently from what it is. Every nmat tool passes such names through here.

use std::borrow::Cow;

/// `name` with every character a terminal would act on (C0 and C1 controls, DEL, escape
/// sequences' ESC) or that changes how text reads (bidirectional overrides and isolates,
/// zero-width characters, byte-order marks) written as a visible `\u{…}` escape; other text is
/// kept, so ordinary names print unchanged.
pub fn for_terminal(name: &str) -> Cow<'_, str> {
    if !name.chars().any(hidden) {
        return Cow::Borrowed(name);
    }
    Cow::Owned(
        name.chars()
            .map(|c| if hidden(c) { c.escape_unicode().to_string() } else { c.to_string() })
            .collect(),
    )
}

/// `name` as a bare file name, safe on Linux, macOS and Windows: characters that are hidden on a
/// terminal (see [`for_terminal`]), path separators and the characters Windows forbids
/// (`< > : " | ? *`) become `_`; a leading `.` (a hidden file, `.` or `..`) and a trailing `.` or
/// space (dropped by Windows) become `_`; a Windows device name (`CON`, `NUL`, `COM1`, …, with or
/// without an extension) gets a `_` in front; an empty name becomes `map`. At most
/// [`MAX_FILE_NAME_BYTES`] bytes, cut at a character boundary.
pub fn file_name(name: &str) -> String {
    let mut out: String = name
        .chars()
        .map(|c| if hidden(c) || "/\\<>:\"|?*".contains(c) { '_' } else { c })
        .collect();
    while out.len() > MAX_FILE_NAME_BYTES {
        out.pop();
    }
    if out.is_empty() {
        return "map".into();
    }
    if out.starts_with('.') {
        out.replace_range(..1, "_");
    }
    if out.ends_with(['.', ' ']) {
        out.pop();
        out.push('_');
    }
    let stem = out.split('.').next().unwrap_or("").to_ascii_uppercase();
    let device = matches!(stem.as_str(), "CON" | "PRN" | "AUX" | "NUL")
        || (stem.len() == 4
            && (stem.starts_with("COM") || stem.starts_with("LPT"))
            && stem.ends_with(|c: char| c.is_ascii_digit()));
    if device {
        out.insert(0, '_');
    }
    out
}

/// The longest file name [`file_name`] returns, in bytes (file systems allow 255; room is left
/// for the mip suffix and extension the tools add).
pub const MAX_FILE_NAME_BYTES: usize = 200;

/// Characters that a terminal acts on or that change how the text around them reads.
fn hidden(c: char) -> bool {
    c.is_control()
        || matches!(c,
            '\u{200B}'..='\u{200F}' // zero-width space, joiners, LRM/RLM
            | '\u{202A}'..='\u{202E}' // bidirectional embeddings and overrides
            | '\u{2066}'..='\u{2069}' // bidirectional isolates
            | '\u{FEFF}' // byte-order mark
        )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ordinary_names_are_kept() {
        for name in ["albedo.png", "brick_normal.tga", "ziegel_fläche.png", "a b-c.tif"] {
            assert_eq!(for_terminal(name), name);
            assert_eq!(file_name(name), name);
        }
    }

    #[test]
    fn escapes_controls_and_bidi_overrides_are_made_visible() {
        let shown = for_terminal("x\u{1b}[2J\ny\u{202e}gnp.exe\0");
        assert_eq!(shown, "x\\u{1b}[2J\\u{a}y\\u{202e}gnp.exe\\u{0}");
        assert!(!shown.chars().any(hidden));
    }

    #[test]
    fn file_names_cannot_leave_the_folder_hide_or_name_a_device() {
        let cases = [
            ("../../etc/passwd", "_._.._etc_passwd"),
            ("..", "__"),
            (".", "_"),
            (".hidden.png", "_hidden.png"),
            ("a\\b.png", "a_b.png"),
            ("a\0b\n.png", "a_b_.png"),
            ("c:evil.png", "c_evil.png"),
            ("name. ", "name._"),
            ("", "map"),
            ("CON", "_CON"),
            ("nul.png", "_nul.png"),
            ("com7.tga", "_com7.tga"),
            ("console.png", "console.png"),
        ];
        for (raw, safe) in cases {
            assert_eq!(file_name(raw), safe, "{raw:?}");
        }
        let long = "é".repeat(300);
        let cut = file_name(&long);
        assert!(cut.len() <= MAX_FILE_NAME_BYTES && cut.chars().all(|c| c == 'é'));
    }
}
