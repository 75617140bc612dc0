//! How figures read in tables, notes and chart labels: bytes, seconds and
//! plain values with about three significant digits.

/// A byte count as `512 B`, `3.2 KiB`, `41.0 MiB`, `1.20 GiB`.
pub fn format_bytes(bytes: usize) -> String {
    let b = bytes as f64;
    const K: f64 = 1024.0;
    if b < K {
        format!("{bytes} B")
    } else if b < K * K {
        format!("{:.1} KiB", b / K)
    } else if b < K * K * K {
        format!("{:.1} MiB", b / (K * K))
    } else {
        format!("{:.2} GiB", b / (K * K * K))
    }
}

/// Seconds as `420 ns`, `3.25 µs`, `850 µs`, `12.3 ms`, `4.56 s`.
pub fn format_seconds(s: f64) -> String {
    if !s.is_finite() {
        s.to_string()
    } else if s < 1e-6 {
        format!("{:.0} ns", s * 1e9)
    } else if s < 1e-4 {
        format!("{:.2} µs", s * 1e6)
    } else if s < 1e-3 {
        format!("{:.0} µs", s * 1e6)
    } else if s < 1.0 {
        format!("{:.1} ms", s * 1e3)
    } else {
        format!("{s:.2} s")
    }
}

/// Formats an axis value with about three significant digits: `0.25`, `1200`,
/// `1e-8`, `3.2e5`.
pub fn format_value(x: f64) -> String {
    if x == 0.0 {
        return "0".to_string();
    }
    if !x.is_finite() {
        return x.to_string();
    }
    let a = x.abs();
    if (1e-3..1e5).contains(&a) {
        let s = format!("{x:.3}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        return s.to_string();
    }
    let s = format!("{x:.2e}");
    let (mantissa, exponent) = s.split_once('e').expect("{:e} formatting has an exponent");
    let mantissa = mantissa.trim_end_matches('0').trim_end_matches('.');
    format!("{mantissa}e{exponent}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_and_seconds_format_readably() {
        assert_eq!(format_bytes(512), "512 B");
        assert_eq!(format_bytes(3 * 1024 * 1024), "3.0 MiB");
        assert_eq!(format_seconds(0.0123), "12.3 ms");
        assert_eq!(format_seconds(2.5), "2.50 s");
        assert_eq!(format_seconds(4.2e-7), "420 ns");
        assert_eq!(format_seconds(3.25e-6), "3.25 µs");
    }

    #[test]
    fn values_format_compactly() {
        assert_eq!(format_value(0.0), "0");
        assert_eq!(format_value(0.25), "0.25");
        assert_eq!(format_value(1200.0), "1200");
        assert_eq!(format_value(1e-8), "1e-8");
        assert_eq!(format_value(-3.25e5), "-3.25e5");
    }
}
