//! How far a URDF's values are trusted, per kind of parameter (relative): the prior `identify` reads a URDF with,
//! and the spread a robot's family is drawn with. One number trusts every kind alike; a URDF whose masses come from
//! a scale and whose centres of mass are CAD's, or placeholders, is trusted per kind
//! (`--spread 0.3,com=0.1`).

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Largest spread of any kind: a mass believed within a factor of e^3 (20) either way is no prior, and draws from
/// a wider one are bodies no simulator steps (`generate --spread 100` failed every job).
pub const MAX_SPREAD: f64 = 3.0;

/// Relative spread per kind: masses, centres of mass, inertia tensors, joint friction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "Written", into = "Written")]
pub struct Spread {
    pub mass: f64,
    pub com: f64,
    pub inertia: f64,
    pub friction: f64,
}

/// As a manifest or a cache key holds it: one number when every kind has the same (what manifests held before the
/// kinds could differ), else a table.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
enum Written {
    Uniform(f64),
    Kinds { mass: f64, com: f64, inertia: f64, friction: f64 },
}

impl From<Written> for Spread {
    fn from(w: Written) -> Self {
        match w {
            Written::Uniform(s) => Spread::uniform(s),
            Written::Kinds { mass, com, inertia, friction } => Spread { mass, com, inertia, friction },
        }
    }
}

impl From<Spread> for Written {
    fn from(s: Spread) -> Self {
        match s.is_uniform() {
            true => Written::Uniform(s.mass),
            false => Written::Kinds { mass: s.mass, com: s.com, inertia: s.inertia, friction: s.friction },
        }
    }
}

impl Spread {
    /// Every kind trusted alike.
    pub const fn uniform(s: f64) -> Self {
        Spread { mass: s, com: s, inertia: s, friction: s }
    }

    pub fn is_uniform(&self) -> bool {
        self.com == self.mass && self.inertia == self.mass && self.friction == self.mass
    }
}

impl fmt::Display for Spread {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.is_uniform() {
            true => write!(f, "{}", self.mass),
            false => {
                write!(f, "mass={},com={},inertia={},friction={}", self.mass, self.com, self.inertia, self.friction)
            }
        }
    }
}

/// A spread refused, saying what a spread is.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct SpreadError(String);

/// What `--spread` takes, for its errors.
const FORMS: &str = "a positive number (at most 3) for every kind, or comma-separated kind=value (kinds: mass, com, inertia, \
                     friction) after an optional number for the rest, e.g. 0.3,com=0.1";

impl FromStr for Spread {
    type Err = SpreadError;

    /// `0.3`, `0.3,com=0.1` or `mass=0.2,com=0.1,inertia=0.3,friction=0.3`.
    fn from_str(s: &str) -> Result<Self, SpreadError> {
        let refuse = |what: String| SpreadError(format!("{what}: expected {FORMS}"));
        let number = |text: &str, what: &str| match text.trim().parse::<f64>() {
            Ok(v) if v > 0.0 && v <= MAX_SPREAD => Ok(v),
            Ok(v) if v > MAX_SPREAD => Err(refuse(format!("{what}: {v} is more than {MAX_SPREAD}"))),
            _ => Err(refuse(format!("{what}: expected a positive finite number"))),
        };
        let mut kinds: [Option<f64>; 4] = [None; 4];
        let mut rest = None;
        for (k, item) in s.split(',').enumerate() {
            match item.split_once('=') {
                None if k == 0 => rest = Some(number(item, &format!("'{item}'"))?),
                None => return Err(refuse(format!("'{item}' names no kind"))),
                Some((kind, value)) => {
                    let at = ["mass", "com", "inertia", "friction"]
                        .iter()
                        .position(|n| *n == kind.trim())
                        .ok_or_else(|| refuse(format!("'{kind}' is no kind")))?;
                    if kinds[at].is_some() {
                        return Err(refuse(format!("'{kind}' is given twice")));
                    }
                    kinds[at] = Some(number(value, kind)?);
                }
            }
        }
        let value = |k: usize| kinds[k].or(rest).ok_or_else(|| refuse(format!("'{s}' leaves a kind without a value")));
        Ok(Spread { mass: value(0)?, com: value(1)?, inertia: value(2)?, friction: value(3)? })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_number_kinds_and_a_number_with_kinds_parse() {
        assert_eq!("0.3".parse::<Spread>().unwrap(), Spread::uniform(0.3));
        let s: Spread = "0.3,com=0.1".parse().unwrap();
        assert_eq!(s, Spread { mass: 0.3, com: 0.1, inertia: 0.3, friction: 0.3 });
        let all: Spread = "mass=0.2,com=0.1,inertia=0.4,friction=0.5".parse().unwrap();
        assert_eq!(all, Spread { mass: 0.2, com: 0.1, inertia: 0.4, friction: 0.5 });
        assert_eq!(all.to_string().parse::<Spread>().unwrap(), all);
        for bad in ["", "-1", "com=0.1", "0.3,size=0.1", "0.3,com=nan", "0.3,0.2", "0.3,com", "100", "0.3,com=1e9"] {
            let e = bad.parse::<Spread>().expect_err(bad).to_string();
            assert!(e.contains("expected a positive number"), "{bad}: {e}");
        }
        let e = "0.3,com=0.1,com=0.2".parse::<Spread>().expect_err("a kind twice").to_string();
        assert!(e.contains("'com' is given twice"), "{e}");
        assert!("100".parse::<Spread>().expect_err("absurd").to_string().contains("100 is more than 3"));
    }

    /// A manifest written before the kinds could differ holds one number, and reads back as that number for every
    /// kind; a uniform spread is still written as one number, a mixed one as a table.
    #[test]
    fn manifests_hold_one_number_or_a_table() {
        #[derive(Serialize, Deserialize, PartialEq, Debug)]
        struct Holder {
            spread: Spread,
        }
        let old: Holder = toml::from_str("spread = 0.3").unwrap();
        assert_eq!(old.spread, Spread::uniform(0.3));
        assert_eq!(toml::to_string(&old).unwrap().trim(), "spread = 0.3");
        let mixed = Holder { spread: "0.3,com=0.1".parse().unwrap() };
        let text = toml::to_string(&mixed).unwrap();
        assert!(text.contains("com = 0.1"), "{text}");
        assert_eq!(toml::from_str::<Holder>(&text).unwrap(), mixed);
    }
}
