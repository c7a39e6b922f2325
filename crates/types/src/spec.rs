//! Parameter registry: every numeric config field with its unit, meaning and admissible range.
//!
//! Hopsan-style: a component declares its parameters (name, unit, description) once, on the
//! struct field that stores it (`#[param(...)]`, `#[derive(Params)]`); the loader, the error
//! messages, `ehactl params`, the Python bindings and the fit's path accessor all read what the
//! derive generates from that one declaration ([`table`], [`ParamTree`]). The plant's own table is
//! `ehactl_plant::spec::params`; the rig sections' are assembled by `ehactl-config`.

use std::fmt;

/// Admissible range of a parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Range {
    /// Any finite value.
    Finite,
    /// Finite and > 0.
    Positive,
    /// Finite and ≥ 0.
    NonNegative,
    /// Finite and within [lo, hi].
    Within(f64, f64),
    /// Finite, > 0 and ≤ hi: a physical quantity with a plausible upper bound.
    PositiveAtMost(f64),
}

impl Range {
    /// Whether `v` is admissible.
    pub fn admits(self, v: f64) -> bool {
        if !v.is_finite() {
            return false;
        }
        match self {
            Range::Finite => true,
            Range::Positive => v > 0.0,
            Range::NonNegative => v >= 0.0,
            Range::Within(lo, hi) => v >= lo && v <= hi,
            Range::PositiveAtMost(hi) => v > 0.0 && v <= hi,
        }
    }

    /// Human description of the range.
    pub fn describe(self) -> String {
        match self {
            Range::Finite => "a finite number".into(),
            Range::Positive => "a finite number > 0".into(),
            Range::NonNegative => "a finite number ≥ 0".into(),
            Range::Within(lo, hi) => {
                format!("a finite number in [{}, {}]", readable(lo), readable(hi))
            }
            Range::PositiveAtMost(hi) => format!("a finite number > 0 and ≤ {}", readable(hi)),
        }
    }
}

/// `v` in plain notation between 1e-4 and 1e9 in magnitude (and 0), else in scientific
/// notation: a value of 1.7e308 reads `1.7e308`, not 309 digits (error messages, events).
pub fn readable(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || (1e-4..1e9).contains(&a) || !v.is_finite() {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Kind of value a parameter holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Floating point number.
    Float,
    /// Non-negative integer.
    Integer,
    /// Array of floats.
    FloatArray,
    /// Boolean (`true` / `false`).
    Bool,
    /// One of the listed strings.
    Choice(&'static [&'static str]),
}

/// What else the diagnosis does with an uncertain nominal parameter, declared in its
/// `uncertain(…)` as `role = loop_param` or `role = flow_gain`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Refit with the other nominal parameters, nothing more.
    Nominal,
    /// A parameter of the rig's position loop (the valve's bandwidth, the loop's delay, the
    /// valve's null offset and dead band): a stated uncertainty marks the loop as an
    /// assumption, identified first on the position channel (`ehactl_ident::loopid`).
    Loop,
    /// A valve flow gain (one per flow form): with a proportional loop part of the loop
    /// gain, identified with the loop.
    FlowGain,
}

/// A nominal parameter's role in `ehactl diagnose`, declared on its field with
/// `#[param(…, uncertain(order = N, default, to_range_end, role = …, needs_order = K))]`: a
/// config may state its uncertainty in `[uncertainty]`, and the diagnosis refits it within
/// that range.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Uncertain {
    /// Place in the order the diagnosis refits the nominal parameters (ascending; unique).
    pub order: u16,
    /// Refit by default (± the default uncertainty) when the config is silent about it;
    /// otherwise only when `[uncertainty]` lists it.
    pub default: bool,
    /// Its refit range may reach the lower end of its registry range (a delay, a time
    /// constant, an underlap of 0; a signed null offset may change sign) and is clamped
    /// there; otherwise a range that reaches it is refused.
    pub to_range_end: bool,
    /// What else the diagnosis does with it ([`Role`]).
    pub role: Role,
    /// The model order its section must be configured with for it to be refit (a spool's
    /// bandwidth is a time constant at order 1, a natural frequency at order 2); `None`: any.
    pub needs_order: Option<u8>,
}

/// One declared parameter.
#[derive(Debug, Clone, Copy)]
pub struct Param {
    /// Dotted config path, e.g. `valve.command_full_scale`.
    pub path: &'static str,
    /// SI unit ("-" for dimensionless).
    pub unit: &'static str,
    /// Meaning and seed source.
    pub description: &'static str,
    /// Admissible range.
    pub range: Range,
    /// Value kind.
    pub kind: Kind,
    /// Its role as an uncertain nominal parameter of the diagnosis, if it has one.
    pub uncertain: Option<Uncertain>,
    /// The diagnosis estimates it, or takes it from the data, rather than trusting the
    /// config (declared `estimated` in its `#[param(…)]`): a log's config may differ from
    /// `--config` in it.
    pub estimated: bool,
}

impl Param {
    /// A registry entry; const so that every crate can build its parameter table statically.
    pub const fn new(
        path: &'static str,
        unit: &'static str,
        range: Range,
        description: &'static str,
        kind: Kind,
    ) -> Param {
        Param {
            path,
            unit,
            description,
            range,
            kind,
            uncertain: None,
            estimated: false,
        }
    }

    /// The entry marked as estimated by the diagnosis ([`Param::estimated`]).
    pub const fn with_estimated(self) -> Param {
        Param {
            estimated: true,
            ..self
        }
    }

    /// The entry with its role as an uncertain nominal parameter.
    pub const fn with_uncertain(self, u: Uncertain) -> Param {
        Param {
            uncertain: Some(u),
            ..self
        }
    }

    /// A floating-point entry.
    pub const fn float(
        path: &'static str,
        unit: &'static str,
        range: Range,
        description: &'static str,
    ) -> Param {
        Param::new(path, unit, range, description, Kind::Float)
    }

    /// An integer entry.
    pub const fn int(
        path: &'static str,
        unit: &'static str,
        range: Range,
        description: &'static str,
    ) -> Param {
        Param::new(path, unit, range, description, Kind::Integer)
    }
}

/// Registry entries of a `#[derive(Params)]` struct under `prefix` (e.g. `"canopen"`), in
/// declaration order, with their full dotted paths. Each path string is leaked: call it once
/// per process (from a `LazyLock`, as `ehactl_plant::spec::params` does), so the registry lives as long as the
/// program.
pub fn table<T: ParamTree>(prefix: &str) -> Vec<Param> {
    let mut out = Vec::new();
    T::declare(prefix, &[], &mut out);
    out.into_iter()
        .map(|(path, p)| Param {
            path: Box::leak(path.into_boxed_str()),
            ..p
        })
        .collect()
}

/// The serialised names of the variants of a unit-variant enum `T` (as serde writes them,
/// `rename_all` applied), in declaration order: the choices of a `#[param(choice)]` field,
/// read from the enum's own `Deserialize` so that the list cannot drift from what the loader
/// accepts. Serde's derive passes the list to `Deserializer::deserialize_enum`; a deserializer
/// that only records it is the whole mechanism (serde offers no other public way to list
/// variants). Empty for a type that does not deserialize as an enum.
pub fn variants<T: serde::de::DeserializeOwned>() -> &'static [&'static str] {
    use serde::de::{self, Visitor};
    struct Capture(&'static [&'static str]);
    impl<'de> de::Deserializer<'de> for &mut Capture {
        type Error = de::value::Error;
        fn deserialize_enum<V: Visitor<'de>>(
            self,
            _name: &'static str,
            variants: &'static [&'static str],
            _visitor: V,
        ) -> Result<V::Value, Self::Error> {
            self.0 = variants;
            Err(de::Error::custom("variant names recorded"))
        }
        fn deserialize_any<V: Visitor<'de>>(self, _visitor: V) -> Result<V::Value, Self::Error> {
            Err(de::Error::custom("not an enum"))
        }
        serde::forward_to_deserialize_any! {
            bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
            byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map struct
            identifier ignored_any
        }
    }
    let mut c = Capture(&[]);
    let _ = T::deserialize(&mut c);
    c.0
}

/// Implemented by `#[derive(Params)]` (see the `ehactl-params-derive` crate): the registry
/// entries of a parameter struct and access to its float parameters by dotted path.
pub trait ParamTree: Clone {
    /// Append `(dotted path, entry)` for every declared field under `prefix`, with
    /// per-instance `over`rides applied (the entry's own `path` is left empty).
    fn declare(prefix: &str, over: &[Override], out: &mut Vec<(String, Param)>);
    /// Value of a float parameter at `path` (relative to this struct); `None` for an unknown
    /// path, an absent optional section or value, or a non-float parameter.
    fn param_get(&self, path: &str) -> Option<f64>;
    /// Write a float parameter; an absent optional section on the way is cloned from `tpl`
    /// when it has one, else the write fails with [`PathErrorKind::Absent`].
    fn param_set(&mut self, path: &str, v: f64, tpl: Option<&Self>) -> Result<(), PathErrorKind>;

    /// Whether `path` (relative, `name[i]` for array elements) is a declared parameter.
    fn knows(path: &str) -> bool {
        let base = path.split_once('[').map_or(path, |(b, _)| b);
        let mut out = Vec::new();
        Self::declare("", &[], &mut out);
        out.iter().any(|(p, _)| p == base)
    }
    /// Value of the float parameter at dotted `path` (`name[i]` for an array element).
    fn get_path(&self, path: &str) -> Option<f64> {
        self.param_get(path)
    }
    /// Write the float parameter at dotted `path`. Setting a parameter of an effect whose
    /// section is absent is an error ([`PathErrorKind::Absent`]): which start values the
    /// other parameters of a new section get is the caller's decision, see
    /// [`ParamTree::set_path_or_insert`].
    fn set_path(&mut self, path: &str, v: f64) -> Result<(), PathError> {
        self.param_set(path, v, None).map_err(|kind| PathError {
            path: path.to_string(),
            kind,
        })
    }
    /// As [`ParamTree::set_path`], but an absent optional section on the path is first
    /// copied from `template`.
    fn set_path_or_insert(&mut self, path: &str, v: f64, template: &Self) -> Result<(), PathError> {
        self.param_set(path, v, Some(template))
            .map_err(|kind| PathError {
                path: path.to_string(),
                kind,
            })
    }
}

/// Per-instance change of a nested struct's declaration (`#[param(nested, with(...))]`).
#[derive(Debug, Clone, Copy)]
pub struct Override {
    /// Field name inside the nested struct.
    pub field: &'static str,
    /// Replacement unit.
    pub unit: Option<&'static str>,
    /// Replacement range.
    pub range: Option<Range>,
    /// Replacement description.
    pub desc: Option<&'static str>,
    /// Replacement choices (makes the entry a [`Kind::Choice`]).
    pub choices: Option<&'static [&'static str]>,
}

impl Override {
    /// `p` with the override for `field` in `over` applied.
    pub fn apply(over: &[Override], field: &str, mut p: Param) -> Param {
        for o in over.iter().filter(|o| o.field == field) {
            if let Some(u) = o.unit {
                p.unit = u;
            }
            if let Some(r) = o.range {
                p.range = r;
            }
            if let Some(d) = o.desc {
                p.description = d;
            }
            if let Some(c) = o.choices {
                p.kind = Kind::Choice(c);
            }
        }
        p
    }
}

/// `prefix.key` (or `key` at the root).
pub fn join(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

/// `i` of `<head>i]` (array element paths such as `frequencies[1]`).
pub fn index_of(path: &str, head: &str) -> Option<usize> {
    path.strip_prefix(head)?.strip_suffix(']')?.parse().ok()
}

/// Why a path access failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathErrorKind {
    /// No parameter is declared at this path.
    Unknown,
    /// The parameter is not a float (integer, choice or whole array).
    NotFloat,
    /// The optional (effect) section holding the parameter is absent.
    Absent,
    /// Array index out of range.
    Index,
}

/// A failed path access, naming the path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PathError {
    /// Dotted path as given.
    pub path: String,
    /// What went wrong.
    pub kind: PathErrorKind,
}

impl fmt::Display for PathError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let what = match self.kind {
            PathErrorKind::Unknown => "no such parameter; see `ehactl params`",
            PathErrorKind::NotFloat => "not a float parameter (integer, boolean, choice or array)",
            PathErrorKind::Absent => "its effect section is absent from the config",
            PathErrorKind::Index => "array index out of range",
        };
        write!(f, "parameter `{}`: {what}", self.path)
    }
}

impl std::error::Error for PathError {}

/// A configuration error that names the field, what is wrong and what was expected.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigError {
    /// Dotted path of the offending field (or section).
    pub path: String,
    /// What is wrong, with the expected unit where one applies.
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "config error at `{}`: {}", self.path, self.message)
    }
}

impl std::error::Error for ConfigError {}

impl ConfigError {
    /// Build an error for `path`.
    pub fn new(path: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// Look a parameter up by dotted path in the given tables.
pub fn find<'a>(tables: &[&'a [Param]], path: &str) -> Option<&'a Param> {
    tables
        .iter()
        .flat_map(|t| t.iter())
        .find(|p| p.path == path)
}

/// "expected … in UNIT (description)" for a known path, or a generic phrase.
pub fn expectation(tables: &[&[Param]], path: &str) -> String {
    match find(tables, path) {
        Some(p) => format!(
            "expected {} in {} ({})",
            p.range.describe(),
            p.unit,
            p.description
        ),
        None => "see `ehactl params` for the expected fields and units".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `PositiveAtMost(hi)` is (0, hi]; its text and large numbers read in scientific form.
    #[test]
    fn an_upper_bound_admits_up_to_it_and_reads_short() {
        let r = Range::PositiveAtMost(1.0e6);
        assert!(r.admits(1.0e6) && r.admits(1e-300));
        assert!(!r.admits(0.0) && !r.admits(1.000001e6) && !r.admits(f64::INFINITY));
        assert_eq!(r.describe(), "a finite number > 0 and ≤ 1000000");
        assert_eq!(
            Range::PositiveAtMost(1.0e11).describe(),
            "a finite number > 0 and ≤ 1e11"
        );
        assert_eq!(readable(1.7e308), "1.7e308");
        assert_eq!(readable(2.5e-7), "2.5e-7");
        assert_eq!(readable(-3.5), "-3.5");
    }
}
