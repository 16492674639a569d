//! Text from input files on its way to a terminal: control characters escaped (an escape sequence in
//! a spec's name must not drive the terminal) and long lines cut (a parse error quoting a 400 KB
//! line must stay readable).

/// Longest line of quoted input an error message keeps.
pub const MAX_QUOTED_LINE: usize = 200;

/// `s` with control characters escaped (`\u{1b}`; newlines kept only when `multiline`) and every
/// line cut to `max_line` characters, saying how much was cut.
pub fn for_terminal(s: &str, max_line: usize, multiline: bool) -> String {
    let mut out = String::with_capacity(s.len().min(4096));
    for (i, line) in s.split('\n').enumerate() {
        if i > 0 {
            out.push_str(if multiline { "\n" } else { "\\n" });
        }
        let total = line.chars().count();
        for (kept, c) in line.chars().enumerate() {
            if kept == max_line {
                out.push_str(&format!("… ({} more characters)", total - kept));
                break;
            }
            if c.is_control() && c != '\t' {
                out.extend(c.escape_default());
            } else {
                out.push(c);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_characters_are_escaped_and_long_lines_cut() {
        assert_eq!(for_terminal("g1 \u{1b}[2Jstairs", 200, false), "g1 \\u{1b}[2Jstairs");
        assert_eq!(for_terminal("a\nb", 200, false), "a\\nb");
        assert_eq!(for_terminal("a\nb", 200, true), "a\nb");
        let long = "x".repeat(400_000);
        let cut = for_terminal(&format!("line 1\n{long}\nline 3"), 10, true);
        assert_eq!(cut, "line 1\nxxxxxxxxxx… (399990 more characters)\nline 3");
    }
}
