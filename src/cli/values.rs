//! Parsers of numeric option values with their ranges. Used as clap `value_parser`s together with
//! `allow_negative_numbers` (or `allow_hyphen_values` for values such as `-0.01:0.03:3`), so that
//! `--huber -1` reaches the parser instead of reading as an unknown flag, and clap's error names
//! the option and the value: `invalid value '-1' for '--huber <PX>': must be > 0, got -1`.

/// A finite number.
fn number(text: &str) -> Result<f64, String> {
    let value: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("'{text}' is not a number"))?;
    if value.is_finite() {
        Ok(value)
    } else {
        Err(format!("must be finite, got {text}"))
    }
}

/// A finite number > 0.
pub fn positive(text: &str) -> Result<f64, String> {
    let value = number(text)?;
    if value > 0.0 {
        Ok(value)
    } else {
        Err(format!("must be > 0, got {text}"))
    }
}

/// A finite number ≥ 0.
pub fn non_negative(text: &str) -> Result<f64, String> {
    let value = number(text)?;
    if value >= 0.0 {
        Ok(value)
    } else {
        Err(format!("must be ≥ 0, got {text}"))
    }
}

/// A refractive index: finite and ≥ 1.
pub fn index(text: &str) -> Result<f64, String> {
    let value = number(text)?;
    if value >= 1.0 {
        Ok(value)
    } else {
        Err(format!("a refractive index must be ≥ 1, got {text}"))
    }
}

/// An angle in degrees in [0°, 90°): a board tilt (at 90° the board is edge-on to the camera).
pub fn tilt_below_90(text: &str) -> Result<f64, String> {
    let value = number(text)?;
    if (0.0..90.0).contains(&value) {
        Ok(value)
    } else {
        Err(format!("must lie in [0°, 90°), got {text}"))
    }
}

/// An axis tilt bound in degrees in (0°, 80°), the range calibration searches.
pub fn tilt_bound(text: &str) -> Result<f64, String> {
    let value = number(text)?;
    if value > 0.0 && value < 80.0 {
        Ok(value)
    } else {
        Err(format!("must lie in (0°, 80°), got {text}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_are_checked_and_named() {
        assert_eq!(positive("0.5"), Ok(0.5));
        assert_eq!(positive("-1"), Err("must be > 0, got -1".into()));
        assert!(
            positive("0").is_err()
                && positive("inf").is_err()
                && positive("NaN").is_err()
                && positive("x").is_err()
        );
        assert_eq!(non_negative("0"), Ok(0.0));
        assert!(non_negative("-0.1").is_err());
        assert!(index("0.9").is_err() && index("1.333") == Ok(1.333));
        assert!(
            tilt_below_90("180").is_err()
                && tilt_below_90("-1").is_err()
                && tilt_below_90("90").is_err()
        );
        assert_eq!(tilt_below_90("0"), Ok(0.0));
        assert!(tilt_bound("-5").is_err() && tilt_bound("0").is_err() && tilt_bound("80").is_err());
        assert_eq!(tilt_bound("30"), Ok(30.0));
    }
}
