//! The value rules of the command line's numeric flags, as parsers a flag names (`value_parser = whole(1, MAX)`):
//! a value out of range is refused before anything runs, with what the flag takes, instead of becoming a panic
//! (capacity overflow), an abort (an allocation of terabytes) or a run that means nothing (`--lr nan`). Shared by the
//! `dynforge` binary and the trainer's flags.

/// Robots a dataset may have: 12,000 times the paper's 8192. Far more is a typing mistake, and a run of that size
/// would write petabytes.
pub const MAX_ROBOTS: u64 = 100_000_000;

/// A flag's value refused, saying what the flag takes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct FlagError(String);

impl From<&str> for FlagError {
    fn from(what: &str) -> Self {
        FlagError(what.to_string())
    }
}

/// A parser of whole numbers from `lo` to `hi`.
pub fn whole<T>(lo: u64, hi: u64) -> impl Fn(&str) -> Result<T, FlagError> + Clone + Send + Sync + 'static
where
    T: TryFrom<u64>,
{
    move |s: &str| {
        let refuse = || FlagError(format!("expected a whole number from {lo} to {hi}"));
        let v: u64 = s.trim().parse().map_err(|_| refuse())?;
        if !(lo..=hi).contains(&v) {
            return Err(refuse());
        }
        T::try_from(v).map_err(|_| refuse())
    }
}

/// A finite number above 0.
pub fn positive(s: &str) -> Result<f64, FlagError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err("expected a positive finite number".into()),
    }
}

/// A finite number of at least 0.
pub fn non_negative(s: &str) -> Result<f64, FlagError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err("expected a finite number of at least 0".into()),
    }
}

/// A share strictly between 0 and 1 (a validation split: both sides must have something).
pub fn share(s: &str) -> Result<f64, FlagError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v < 1.0 => Ok(v),
        _ => Err("expected a number between 0 and 1 (exclusive)".into()),
    }
}

/// A joint to weld, `NAME` or `NAME=POSITION` (the position defaults to 0).
pub fn weld(s: &str) -> Result<(String, f64), FlagError> {
    match s.split_once('=') {
        None => Ok((s.to_string(), 0.0)),
        Some((name, at)) => match at.trim().parse::<f64>() {
            Ok(v) if v.is_finite() => Ok((name.to_string(), v)),
            _ => Err(FlagError(format!("expected NAME or NAME=POSITION, and '{at}' is not a finite number"))),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn out_of_range_values_are_refused_saying_what_is_taken() {
        let robots = whole::<u64>(1, MAX_ROBOTS);
        assert_eq!(robots("8192"), Ok(8192));
        for bad in ["-1", "0", "1e9", "10000000000", "18446744073709551616", "x", ""] {
            assert_eq!(robots(bad), Err("expected a whole number from 1 to 100000000".into()), "{bad}");
        }
        assert_eq!(whole::<u8>(0, 1000)("300"), Err("expected a whole number from 0 to 1000".into()));
        assert_eq!(positive("5e-4"), Ok(5e-4));
        for bad in ["nan", "inf", "-1", "0", "x"] {
            assert!(positive(bad).is_err(), "{bad}");
        }
        assert_eq!(non_negative("0"), Ok(0.0));
        assert!(non_negative("-1e-3").is_err() && non_negative("inf").is_err());
        assert_eq!(share("0.2"), Ok(0.2));
        for bad in ["0", "1", "nan", "-0.1", "x"] {
            assert!(share(bad).is_err(), "{bad}");
        }
        assert_eq!(weld("finger"), Ok(("finger".into(), 0.0)));
        assert_eq!(weld("finger=0.02"), Ok(("finger".into(), 0.02)));
        assert!(weld("finger=nan").is_err() && weld("finger=").is_err());
    }
}
