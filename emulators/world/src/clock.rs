//! How emulated time relates to the wall clock, shared by every emulated device family.

use std::fmt;
use std::str::FromStr;

/// How emulated time relates to the wall clock.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Clock {
    /// Simulated seconds per wall second (1.0 = real time).
    Scaled(f64),
    /// Motion completes as soon as something depends on it.
    Unconstrained,
}

/// A `--time-scale` value that is neither a positive number nor `unconstrained`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "time scale `{0}`: a positive number of simulated seconds per wall second, or `unconstrained`"
)]
pub struct ClockParseError(pub String);

impl FromStr for Clock {
    type Err = ClockParseError;

    /// `unconstrained` (any case) or a positive finite scale such as `1` or `10`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.eq_ignore_ascii_case("unconstrained") {
            return Ok(Clock::Unconstrained);
        }
        match s.parse::<f64>() {
            Ok(k) if k.is_finite() && k > 0.0 => Ok(Clock::Scaled(k)),
            _ => Err(ClockParseError(s.to_string())),
        }
    }
}

impl fmt::Display for Clock {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Clock::Scaled(k) => write!(f, "{k}"),
            Clock::Unconstrained => f.write_str("unconstrained"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_scales_and_unconstrained_and_names_bad_values() {
        assert_eq!("10".parse::<Clock>(), Ok(Clock::Scaled(10.0)));
        assert_eq!("Unconstrained".parse::<Clock>(), Ok(Clock::Unconstrained));
        for bad in ["0", "-1", "nan", "inf", "fast", ""] {
            let e = bad.parse::<Clock>().unwrap_err();
            assert!(e.to_string().contains(&format!("`{bad}`")), "{e}");
        }
        assert_eq!(
            Clock::Scaled(2.5).to_string().parse::<Clock>(),
            Ok(Clock::Scaled(2.5))
        );
    }
}
