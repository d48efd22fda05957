//! How plan values appear in trajectory ids and file names, and the characters an id may use.

/// Depth as it appears in trajectory ids: shortest decimal form with at least one decimal, up to
/// micrometre precision (`0.2`, `0.25`, `1.0`).
pub fn format_depth_mm(depth_mm: f64) -> String {
    let mut s = format!("{depth_mm:.3}");
    while s.ends_with('0') && !s.ends_with(".0") {
        s.pop();
    }
    s
}

/// Angle as it appears in trajectory ids: three integer digits (`030`), with decimals only when
/// needed (`022.5`).
pub fn format_angle_deg(angle_deg: f64) -> String {
    let rounded = (angle_deg * 1000.0).round() / 1000.0;
    if rounded.fract() == 0.0 {
        format!("{:03}", rounded as i64)
    } else {
        let mut s = format!("{rounded:07.3}");
        while s.ends_with('0') {
            s.pop();
        }
        s
    }
}

/// Whether `c` may appear in an id that names files (a sensor id, an indenter name): ASCII
/// letters and digits, `_`, `-` and `.`.
pub fn is_id_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.')
}

/// Whether every character of `id` may appear in an id (see [`is_id_char`]); true for "".
pub fn is_id(id: &str) -> bool {
    id.chars().all(is_id_char)
}
