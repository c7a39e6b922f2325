//! Fixed-size per-cycle records and events (copper-rs style: preallocated, serialised after
//! the cycle by the logger thread), with their ROS 2 message schemas and CDR encoding so
//! Foxglove plots every field directly.

use ehactl_types::{Measurements, PlantState};

/// Everything that happened in one control cycle.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleRecord {
    /// Cycle index from 0.
    pub cycle: u64,
    /// Cycle time (s).
    pub t: f64,
    /// Setpoint (N or m).
    pub setpoint: f64,
    /// Setpoint rate (N/s or m/s).
    pub setpoint_rate: f64,
    /// Feedback used by the controller (N or m).
    pub feedback: f64,
    /// Error setpoint − feedback (N or m).
    pub error: f64,
    /// Command sent to the valve (V).
    pub command: f64,
    /// Command before limits (V).
    pub command_unsat: f64,
    /// Proportional term (V).
    pub p_term: f64,
    /// Integral term (V).
    pub i_term: f64,
    /// Derivative term (V).
    pub d_term: f64,
    /// Feed-forward term (V).
    pub ff_term: f64,
    /// Sensor readings.
    pub meas: Measurements,
    /// Ground-truth plant state (simulation only; `has_plant` says whether it is valid).
    pub plant: PlantState,
    /// Whether `plant` is valid.
    pub has_plant: bool,
    /// Wall-clock timing of the cycle (wall-clock pacers only; logged on `/timing`).
    pub timing: Option<CycleTiming>,
}

pub use ehactl_types::event::{Event, EventKind, Severity};
pub use ehactl_types::timing::CycleTiming;

/// Field names of the `/control` message after `cycle` (all float64), in order.
pub const CONTROL_FIELDS: [&str; 16] = [
    "t",
    "setpoint",
    "setpoint_rate",
    "feedback",
    "error",
    "command",
    "command_unsat",
    "p_term",
    "i_term",
    "d_term",
    "ff_term",
    "force",
    "position",
    "p_a",
    "p_b",
    "spool",
];

/// Field names of the `/plant` message before `stuck` (all float64), in order.
pub const PLANT_FIELDS: [&str; 16] = [
    "t",
    "command",
    "spool",
    "spool_velocity",
    "p_a",
    "p_b",
    "p_s",
    "x",
    "v",
    "x_load",
    "v_load",
    "q_a",
    "q_b",
    "friction",
    "external",
    "rod_force",
];

/// ros2msg schema text of `/control`.
pub fn control_schema() -> String {
    let mut s = String::from(
        "# One control cycle of ehactl (SI units: s, N or m, V, Pa; spool as fraction of travel)\nuint64 cycle\n",
    );
    for f in CONTROL_FIELDS {
        s.push_str("float64 ");
        s.push_str(f);
        s.push('\n');
    }
    s
}

/// ros2msg schema text of `/plant`.
pub fn plant_schema() -> String {
    let mut s = String::from("# Ground-truth plant state of the ehactl simulation (SI units)\n");
    for f in PLANT_FIELDS {
        s.push_str("float64 ");
        s.push_str(f);
        s.push('\n');
    }
    s.push_str("bool stuck\n");
    s
}

/// The plant state of the `/plant` values in [`PLANT_FIELDS`] order and the `stuck` flag: the
/// one place that names the float64 fields by position (the inverse of
/// [`CycleRecord::plant_values`]).
pub fn plant_state(values: [f64; 16], stuck: bool) -> PlantState {
    let [t, command, spool, spool_velocity, p_a, p_b, p_s, x, v, x_load, v_load, q_a, q_b, friction, external, rod_force] =
        values;
    PlantState {
        t,
        command,
        spool,
        spool_velocity,
        p_a,
        p_b,
        p_s,
        x,
        v,
        x_load,
        v_load,
        q_a,
        q_b,
        friction,
        external,
        rod_force,
        stuck,
    }
}

/// Field names of the `/timing` message after `cycle` and `t` (all float64), in order;
/// then `uint32 skipped`, `bool overrun` and `bool overrun_exec` (appended 2026-11-26;
/// readers of the older layout, which ends at `overrun`, still read a prefix).
pub const TIMING_FIELDS: [&str; 4] = ["wall_t", "lateness_us", "period_us", "exec_prev_us"];

/// ros2msg schema text of `/timing`.
pub fn timing_schema() -> String {
    let mut s = String::from(
        "# Wall-clock timing of one ehactl cycle (CLOCK_MONOTONIC; wall_t in s, the rest in us)\nuint64 cycle\nfloat64 t\n",
    );
    for f in TIMING_FIELDS {
        s.push_str("float64 ");
        s.push_str(f);
        s.push('\n');
    }
    s.push_str("uint32 skipped\nbool overrun\nbool overrun_exec\n");
    s
}

/// CDR little-endian encapsulation header.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

impl CycleRecord {
    /// Values of the `/control` message in [`CONTROL_FIELDS`] order.
    pub fn control_values(&self) -> [f64; 16] {
        let m = &self.meas;
        [
            self.t,
            self.setpoint,
            self.setpoint_rate,
            self.feedback,
            self.error,
            self.command,
            self.command_unsat,
            self.p_term,
            self.i_term,
            self.d_term,
            self.ff_term,
            m.force,
            m.position,
            m.p_a,
            m.p_b,
            m.spool,
        ]
    }

    /// Values of the `/plant` message in [`PLANT_FIELDS`] order (the inverse of
    /// [`plant_state`]).
    pub fn plant_values(&self) -> [f64; 16] {
        let p = &self.plant;
        [
            p.t,
            p.command,
            p.spool,
            p.spool_velocity,
            p.p_a,
            p.p_b,
            p.p_s,
            p.x,
            p.v,
            p.x_load,
            p.v_load,
            p.q_a,
            p.q_b,
            p.friction,
            p.external,
            p.rod_force,
        ]
    }

    /// CDR encoding of `/control` into `buf` (cleared first).
    pub fn encode_control(&self, buf: &mut Vec<u8>) {
        buf.clear();
        self.append_control(buf);
    }

    /// CDR encoding of `/control` appended to `buf` (the MCAP writer's chunk).
    #[inline]
    pub fn append_control(&self, buf: &mut Vec<u8>) {
        buf.extend_from_slice(&CDR_LE);
        buf.extend_from_slice(&self.cycle.to_le_bytes());
        for v in self.control_values() {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }

    /// CDR encoding of `/timing` into `buf` (cleared first); false if the record has no
    /// timing. Layout: cycle u64, t and [`TIMING_FIELDS`] f64, skipped u32, overrun u8,
    /// overrun_exec u8 (every field naturally aligned, so no padding).
    pub fn encode_timing(&self, buf: &mut Vec<u8>) -> bool {
        buf.clear();
        self.append_timing(buf)
    }

    /// CDR encoding of `/timing` appended to `buf`; false (nothing appended) if the record
    /// has no timing.
    #[inline]
    pub fn append_timing(&self, buf: &mut Vec<u8>) -> bool {
        let Some(tm) = self.timing else {
            return false;
        };
        buf.extend_from_slice(&CDR_LE);
        buf.extend_from_slice(&self.cycle.to_le_bytes());
        for v in [
            self.t,
            tm.wall_t,
            tm.lateness_us,
            tm.period_us,
            tm.exec_prev_us,
        ] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.extend_from_slice(&tm.skipped.to_le_bytes());
        buf.push(tm.overrun as u8);
        buf.push(tm.overrun_exec as u8);
        true
    }

    /// CDR encoding of `/plant` into `buf` (cleared first).
    pub fn encode_plant(&self, buf: &mut Vec<u8>) {
        buf.clear();
        self.append_plant(buf);
    }

    /// CDR encoding of `/plant` appended to `buf` (the MCAP writer's chunk).
    #[inline]
    pub fn append_plant(&self, buf: &mut Vec<u8>) {
        buf.extend_from_slice(&CDR_LE);
        for v in self.plant_values() {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.push(self.plant.stuck as u8);
    }
}

// ---------------------------------------------------------------------------------------
// Decoding: the one reader of the log format, beside its encoder. `decode_*` read the
// fields in the same order as `encode_*` write them (a cursor, no byte offsets);
// [`FlatSchema`] reads any flat CDR message from the ros2msg schema text published in the
// log itself (used by the Python bindings for every CDR channel, whatever it holds).

/// Why a logged message cannot be decoded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DecodeError {
    /// The payload has the wrong size for its layout.
    Length {
        /// Message kind, e.g. `/control`.
        what: String,
        /// Bytes found.
        len: usize,
        /// Bytes the layout needs (CDR header included).
        expected: usize,
    },
    /// The 4-byte CDR encapsulation header is not plain CDR (`00 00` big or `00 01` little endian).
    Encapsulation {
        /// Message kind.
        what: String,
        /// The header bytes found.
        header: [u8; 4],
    },
    /// A `bool` field holds a byte other than 0 or 1.
    Bool {
        /// Message kind.
        what: String,
        /// Field name.
        field: String,
        /// The byte found.
        byte: u8,
    },
    /// A ros2msg schema line cannot be used by the flat decoder.
    Schema {
        /// Message kind.
        what: String,
        /// What is wrong.
        reason: String,
    },
}

impl std::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DecodeError::Length { what, len, expected } => write!(
                f,
                "{what} message of {len} bytes; expected {expected} (4-byte CDR header + fields of its schema)"
            ),
            DecodeError::Encapsulation { what, header } => write!(
                f,
                "{what} message starts with {:02x} {:02x} {:02x} {:02x}; expected a plain CDR header (00 01 00 00 little endian or 00 00 00 00 big endian)",
                header[0], header[1], header[2], header[3]
            ),
            DecodeError::Bool { what, field, byte } => write!(
                f,
                "{what} field `{field}` is a bool but holds byte {byte:#04x}; expected 0 or 1"
            ),
            DecodeError::Schema { what, reason } => write!(f, "{what} schema: {reason}"),
        }
    }
}

impl std::error::Error for DecodeError {}

/// Sequential little-endian CDR reader over one message with exactly `size` bytes of
/// fields after the header (checked up front, so the reads below cannot run short).
struct CdrCursor<'a> {
    what: &'static str,
    b: &'a [u8],
    pos: usize,
}

impl<'a> CdrCursor<'a> {
    fn new(what: &'static str, data: &'a [u8], size: usize) -> Result<Self, DecodeError> {
        if data.len() != CDR_LE.len() + size {
            return Err(DecodeError::Length {
                what: what.into(),
                len: data.len(),
                expected: CDR_LE.len() + size,
            });
        }
        if data[..4] != CDR_LE {
            return Err(DecodeError::Encapsulation {
                what: what.into(),
                header: [data[0], data[1], data[2], data[3]],
            });
        }
        Ok(CdrCursor {
            what,
            b: &data[4..],
            pos: 0,
        })
    }
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.b[self.pos..self.pos + N]);
        self.pos += N;
        a
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
    fn f64s<const N: usize>(&mut self) -> [f64; N] {
        std::array::from_fn(|_| self.f64())
    }
    fn bool(&mut self, field: &str) -> Result<bool, DecodeError> {
        match self.take::<1>()[0] {
            0 => Ok(false),
            1 => Ok(true),
            byte => Err(DecodeError::Bool {
                what: self.what.into(),
                field: field.into(),
                byte,
            }),
        }
    }
}

/// One `/timing` message: cycle index, cycle time (s) and the wall-clock timing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimingMessage {
    /// Cycle index.
    pub cycle: u64,
    /// Cycle time (s).
    pub t: f64,
    /// Wall-clock timing of the cycle.
    pub timing: CycleTiming,
}

impl CycleRecord {
    /// Decode a `/control` message written by [`CycleRecord::encode_control`]. The result
    /// has no plant state (`has_plant` false) and no timing; `meas.t` is the cycle time.
    pub fn decode_control(data: &[u8]) -> Result<CycleRecord, DecodeError> {
        let mut c = CdrCursor::new("/control", data, 8 + 8 * CONTROL_FIELDS.len())?;
        let cycle = c.u64();
        let [t, setpoint, setpoint_rate, feedback, error, command, command_unsat, p_term, i_term, d_term, ff_term, force, position, p_a, p_b, spool] =
            c.f64s::<16>();
        Ok(CycleRecord {
            cycle,
            t,
            setpoint,
            setpoint_rate,
            feedback,
            error,
            command,
            command_unsat,
            p_term,
            i_term,
            d_term,
            ff_term,
            meas: Measurements {
                t,
                force,
                position,
                p_a,
                p_b,
                spool,
            },
            plant: PlantState::default(),
            has_plant: false,
            timing: None,
        })
    }

    /// Decode a `/plant` message written by [`CycleRecord::encode_plant`].
    pub fn decode_plant(data: &[u8]) -> Result<PlantState, DecodeError> {
        let mut c = CdrCursor::new("/plant", data, 8 * PLANT_FIELDS.len() + 1)?;
        let values = c.f64s::<16>();
        let stuck = c.bool("stuck")?;
        Ok(plant_state(values, stuck))
    }

    /// Decode a `/timing` message written by [`CycleRecord::encode_timing`]. Messages of
    /// logs written before 2026-11-26 end at `overrun` (one byte shorter, their schema has
    /// no `overrun_exec`); they decode with `overrun_exec` false.
    pub fn decode_timing(data: &[u8]) -> Result<TimingMessage, DecodeError> {
        let old = 8 + 8 * (1 + TIMING_FIELDS.len()) + 4 + 1;
        let size = if data.len() == CDR_LE.len() + old {
            old
        } else {
            old + 1
        };
        let mut c = CdrCursor::new("/timing", data, size)?;
        let cycle = c.u64();
        let [t, wall_t, lateness_us, period_us, exec_prev_us] = c.f64s::<5>();
        let skipped = c.u32();
        let overrun = c.bool("overrun")?;
        let overrun_exec = if size > old {
            c.bool("overrun_exec")?
        } else {
            false
        };
        Ok(TimingMessage {
            cycle,
            t,
            timing: CycleTiming {
                wall_t,
                lateness_us,
                period_us,
                exec_prev_us,
                skipped,
                overrun,
                overrun_exec,
            },
        })
    }
}

/// A primitive ros2msg field type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Prim {
    /// `float64`
    F64,
    /// `float32`
    F32,
    /// `int64`
    I64,
    /// `int32`
    I32,
    /// `int16`
    I16,
    /// `int8`
    I8,
    /// `uint64`
    U64,
    /// `uint32`
    U32,
    /// `uint16`
    U16,
    /// `uint8`, `byte`, `char`
    U8,
    /// `bool`
    Bool,
}

impl Prim {
    /// The primitive named `s` in a ros2msg schema.
    pub fn parse(s: &str) -> Option<Prim> {
        Some(match s {
            "float64" => Prim::F64,
            "float32" => Prim::F32,
            "int64" => Prim::I64,
            "int32" => Prim::I32,
            "int16" => Prim::I16,
            "int8" => Prim::I8,
            "uint64" => Prim::U64,
            "uint32" => Prim::U32,
            "uint16" => Prim::U16,
            "uint8" | "byte" | "char" => Prim::U8,
            "bool" => Prim::Bool,
            _ => return None,
        })
    }

    /// Size and CDR alignment (bytes).
    pub fn size(self) -> usize {
        match self {
            Prim::F64 | Prim::I64 | Prim::U64 => 8,
            Prim::F32 | Prim::I32 | Prim::U32 => 4,
            Prim::I16 | Prim::U16 => 2,
            Prim::I8 | Prim::U8 | Prim::Bool => 1,
        }
    }
}

/// One decoded field value of a flat message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    /// `float64`, `float32`.
    F(f64),
    /// Signed integers.
    I(i64),
    /// Unsigned integers (`uint8`, `byte`, `char` included).
    U(u64),
    /// `bool`.
    B(bool),
}

/// One field of a flat message: name, type and byte offset after the CDR header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FlatField {
    /// Field name.
    pub name: String,
    /// Type.
    pub prim: Prim,
    /// Byte offset after the 4-byte CDR header (CDR alignment applied).
    pub offset: usize,
}

/// Layout of a flat ros2msg message (primitive fields only, the kind ehactl logs), read
/// from the schema text; decodes CDR payloads of either byte order. Alignment follows
/// XCDR1 as used by ROS 2: each primitive aligned to its size, counted from the end of the
/// encapsulation header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FlatSchema {
    /// Message kind, for errors (topic or schema name).
    pub what: String,
    /// Fields in order.
    pub fields: Vec<FlatField>,
    /// Bytes of fields after the header.
    pub size: usize,
}

impl FlatSchema {
    /// Parse a ros2msg schema text (comments and constants skipped; the first `====`
    /// separator ends the message, as dependent definitions follow it).
    pub fn parse_ros2msg(what: &str, schema: &str) -> Result<FlatSchema, DecodeError> {
        let bad = |reason: String| DecodeError::Schema {
            what: what.into(),
            reason,
        };
        let mut fields = Vec::new();
        let mut off = 0usize;
        for raw in schema.lines() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            if line.starts_with("====") {
                break;
            }
            let mut it = line.split_whitespace();
            let (Some(ty), Some(name)) = (it.next(), it.next()) else {
                return Err(bad(format!(
                    "cannot parse line `{raw}`; expected `TYPE NAME`"
                )));
            };
            if name.contains('=') || it.next().is_some_and(|t| t.starts_with('=')) {
                continue; // constant
            }
            let Some(prim) = Prim::parse(ty) else {
                return Err(bad(format!(
                    "field `{name}` has type `{ty}`; only flat messages of primitive fields are supported"
                )));
            };
            let a = prim.size();
            off = off.div_ceil(a) * a;
            fields.push(FlatField {
                name: name.to_string(),
                prim,
                offset: off,
            });
            off += a;
        }
        Ok(FlatSchema {
            what: what.into(),
            fields,
            size: off,
        })
    }

    /// Decode one payload, calling `out(field index, value)` for every field in order.
    /// Bytes after the last field (a newer writer's extra fields, CDR end padding) are ignored.
    pub fn decode(
        &self,
        data: &[u8],
        mut out: impl FnMut(usize, Value),
    ) -> Result<(), DecodeError> {
        if data.len() < 4 + self.size {
            return Err(DecodeError::Length {
                what: self.what.clone(),
                len: data.len(),
                expected: 4 + self.size,
            });
        }
        let le = match (data[0], data[1]) {
            (0x00, 0x01) => true,
            (0x00, 0x00) => false,
            _ => {
                return Err(DecodeError::Encapsulation {
                    what: self.what.clone(),
                    header: [data[0], data[1], data[2], data[3]],
                })
            }
        };
        let b = &data[4..];
        for (i, f) in self.fields.iter().enumerate() {
            let o = f.offset;
            macro_rules! num {
                ($t:ty, $n:literal) => {{
                    let mut a = [0u8; $n];
                    a.copy_from_slice(&b[o..o + $n]);
                    if le {
                        <$t>::from_le_bytes(a)
                    } else {
                        <$t>::from_be_bytes(a)
                    }
                }};
            }
            let v = match f.prim {
                Prim::F64 => Value::F(num!(f64, 8)),
                Prim::F32 => Value::F(num!(f32, 4) as f64),
                Prim::I64 => Value::I(num!(i64, 8)),
                Prim::I32 => Value::I(num!(i32, 4) as i64),
                Prim::I16 => Value::I(num!(i16, 2) as i64),
                Prim::I8 => Value::I(b[o] as i8 as i64),
                Prim::U64 => Value::U(num!(u64, 8)),
                Prim::U32 => Value::U(num!(u32, 4) as u64),
                Prim::U16 => Value::U(num!(u16, 2) as u64),
                Prim::U8 => Value::U(b[o] as u64),
                Prim::Bool => match b[o] {
                    0 => Value::B(false),
                    1 => Value::B(true),
                    byte => {
                        return Err(DecodeError::Bool {
                            what: self.what.clone(),
                            field: f.name.clone(),
                            byte,
                        })
                    }
                },
            };
            out(i, v);
        }
        Ok(())
    }
}

#[cfg(test)]
mod decode_tests {
    use super::*;
    use proptest::prelude::*;

    fn record(
        v: &[f64; 33],
        cycle: u64,
        stuck: bool,
        timing: Option<(u32, bool, bool)>,
    ) -> CycleRecord {
        CycleRecord {
            cycle,
            t: v[0],
            setpoint: v[1],
            setpoint_rate: v[2],
            feedback: v[3],
            error: v[4],
            command: v[5],
            command_unsat: v[6],
            p_term: v[7],
            i_term: v[8],
            d_term: v[9],
            ff_term: v[10],
            meas: Measurements {
                t: v[0],
                force: v[11],
                position: v[12],
                p_a: v[13],
                p_b: v[14],
                spool: v[15],
            },
            // The `/plant` values after the 16 of `/control`, in `PLANT_FIELDS` order.
            plant: plant_state(std::array::from_fn(|i| v[CONTROL_FIELDS.len() + i]), stuck),
            has_plant: true,
            timing: timing.map(|(skipped, overrun, overrun_exec)| CycleTiming {
                wall_t: v[32],
                lateness_us: v[1],
                period_us: v[2],
                exec_prev_us: v[3],
                skipped,
                overrun,
                overrun_exec,
            }),
        }
    }

    fn bits<const N: usize>(a: [f64; N]) -> [u64; N] {
        a.map(f64::to_bits)
    }

    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            proptest::num::f64::ANY,
            Just(f64::NAN),
            Just(f64::INFINITY),
            Just(-0.0),
            -1e7..1e7f64
        ]
    }

    proptest! {
        /// encode → decode gives back every field bit for bit (NaN payloads included),
        /// and the schema-driven decoder reads the same values from the published schema.
        #[test]
        fn roundtrip(v in proptest::array::uniform32(any_f64()), w in any_f64(), cycle in any::<u64>(),
                     stuck in any::<bool>(), skipped in any::<u32>(), overrun in any::<bool>(),
                     overrun_exec in any::<bool>()) {
            let mut a = [0.0; 33];
            a[..32].copy_from_slice(&v);
            a[32] = w;
            let r = record(&a, cycle, stuck, Some((skipped, overrun, overrun_exec)));
            let mut buf = Vec::new();

            r.encode_control(&mut buf);
            let c = CycleRecord::decode_control(&buf).unwrap();
            prop_assert_eq!(c.cycle, cycle);
            prop_assert_eq!(bits(c.control_values()), bits(r.control_values()));
            prop_assert_eq!(c.meas.t.to_bits(), r.t.to_bits());
            let mut again = Vec::new();
            c.encode_control(&mut again);
            prop_assert_eq!(&again, &buf);
            let s = FlatSchema::parse_ros2msg("/control", &control_schema()).unwrap();
            let mut got = Vec::new();
            s.decode(&buf, |_, v| got.push(v)).unwrap();
            prop_assert_eq!(got[0], Value::U(cycle));
            for (g, want) in got[1..].iter().zip(r.control_values()) {
                let Value::F(g) = *g else { panic!("float64 field decoded as {g:?}") };
                prop_assert_eq!(g.to_bits(), want.to_bits());
            }

            r.encode_plant(&mut buf);
            let p = CycleRecord::decode_plant(&buf).unwrap();
            let back = CycleRecord { plant: p, ..r };
            prop_assert_eq!(bits(back.plant_values()), bits(r.plant_values()));
            prop_assert_eq!(p.stuck, stuck);
            let s = FlatSchema::parse_ros2msg("/plant", &plant_schema()).unwrap();
            let mut got = Vec::new();
            s.decode(&buf, |_, v| got.push(v)).unwrap();
            prop_assert_eq!(got.len(), 17);
            prop_assert_eq!(got[16], Value::B(stuck));

            prop_assert!(r.encode_timing(&mut buf));
            let tm = CycleRecord::decode_timing(&buf).unwrap();
            prop_assert_eq!(tm.cycle, cycle);
            prop_assert_eq!(tm.t.to_bits(), r.t.to_bits());
            let rt = r.timing.unwrap();
            prop_assert_eq!(bits([tm.timing.wall_t, tm.timing.lateness_us, tm.timing.period_us, tm.timing.exec_prev_us]),
                            bits([rt.wall_t, rt.lateness_us, rt.period_us, rt.exec_prev_us]));
            prop_assert_eq!((tm.timing.skipped, tm.timing.overrun, tm.timing.overrun_exec),
                            (skipped, overrun, overrun_exec));
            // A message of the older layout (no trailing `overrun_exec`) still
            // decodes, with the flag false.
            let mut old = buf.clone();
            old.pop();
            let to = CycleRecord::decode_timing(&old).unwrap();
            prop_assert_eq!((to.timing.skipped, to.timing.overrun, to.timing.overrun_exec),
                            (skipped, overrun, false));
            let s = FlatSchema::parse_ros2msg("/timing", &timing_schema()).unwrap();
            let mut got = Vec::new();
            s.decode(&buf, |_, v| got.push(v)).unwrap();
            prop_assert_eq!(got[6], Value::U(skipped as u64));
            prop_assert_eq!(got[7], Value::B(overrun));
            prop_assert_eq!(got[8], Value::B(overrun_exec));
        }

        /// Arbitrary bytes never panic any decoder: they decode or give an error.
        #[test]
        fn garbage_never_panics(data in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = CycleRecord::decode_control(&data);
            let _ = CycleRecord::decode_plant(&data);
            let _ = CycleRecord::decode_timing(&data);
            for schema in [control_schema(), plant_schema(), timing_schema()] {
                let s = FlatSchema::parse_ros2msg("x", &schema).unwrap();
                let _ = s.decode(&data, |_, _| {});
            }
        }
    }

    #[test]
    fn short_long_and_corrupt_messages_are_clear_errors() {
        let r = record(&[1.5; 33], 7, false, Some((2, true, false)));
        let mut buf = Vec::new();
        r.encode_control(&mut buf);
        assert_eq!(buf.len(), 4 + 8 + 16 * 8, "the documented /control size");
        let e = CycleRecord::decode_control(&buf[..100]).unwrap_err();
        assert_eq!(
            e,
            DecodeError::Length {
                what: "/control".into(),
                len: 100,
                expected: 140
            }
        );
        assert!(
            e.to_string()
                .starts_with("/control message of 100 bytes; expected 140"),
            "{e}"
        );
        let mut long = buf.clone();
        long.push(0);
        assert!(matches!(
            CycleRecord::decode_control(&long),
            Err(DecodeError::Length { len: 141, .. })
        ));
        let mut be = buf.clone();
        be[1] = 0x00;
        let e = CycleRecord::decode_control(&be).unwrap_err();
        assert!(e.to_string().contains("00 00 00 00"), "{e}");
        assert!(
            CycleRecord::decode_plant(&buf).is_err(),
            "a /control payload is not a /plant one"
        );

        r.encode_plant(&mut buf);
        assert_eq!(buf.len(), 4 + 16 * 8 + 1);
        *buf.last_mut().unwrap() = 2;
        let e = CycleRecord::decode_plant(&buf).unwrap_err();
        assert_eq!(
            e.to_string(),
            "/plant field `stuck` is a bool but holds byte 0x02; expected 0 or 1"
        );
        let s = FlatSchema::parse_ros2msg("/plant", &plant_schema()).unwrap();
        assert!(matches!(
            s.decode(&buf, |_, _| {}),
            Err(DecodeError::Bool { .. })
        ));

        r.encode_timing(&mut buf);
        assert_eq!(buf.len(), 4 + 8 + 5 * 8 + 4 + 1 + 1);
        // One byte short is the older layout without `overrun_exec` (decodes); two short is an error.
        assert!(CycleRecord::decode_timing(&buf[..buf.len() - 1]).is_ok());
        assert!(CycleRecord::decode_timing(&buf[..buf.len() - 2]).is_err());
        let mut long = buf.clone();
        long.push(0);
        assert!(CycleRecord::decode_timing(&long).is_err());
        let mut bad = buf.clone();
        *bad.last_mut().unwrap() = 2;
        assert!(matches!(
            CycleRecord::decode_timing(&bad),
            Err(DecodeError::Bool { .. })
        ));
    }

    /// The schema decoder follows CDR alignment and byte order: a hand-built big-endian
    /// message with padding (uint8 then float64 at offset 8, int16 at 16, float32 at 20).
    #[test]
    fn flat_schema_alignment_and_big_endian() {
        let s = FlatSchema::parse_ros2msg(
            "m",
            "# comment\nuint8 a\nfloat64 b  # trailing\nint16 C=3\nint16 c\nfloat32 d\n================\nMSG: x\nfloat64 z\n",
        )
        .unwrap();
        let offs: Vec<usize> = s.fields.iter().map(|f| f.offset).collect();
        assert_eq!(offs, [0, 8, 16, 20]);
        assert_eq!(s.size, 24);
        let mut m = vec![0x00, 0x00, 0x00, 0x00, 9, 0, 0, 0, 0, 0, 0, 0];
        m.extend_from_slice(&2.5f64.to_be_bytes());
        m.extend_from_slice(&(-3i16).to_be_bytes());
        m.extend_from_slice(&[0, 0]);
        m.extend_from_slice(&0.25f32.to_be_bytes());
        let mut got = Vec::new();
        s.decode(&m, |i, v| got.push((i, v))).unwrap();
        assert_eq!(
            got,
            [
                (0, Value::U(9)),
                (1, Value::F(2.5)),
                (2, Value::I(-3)),
                (3, Value::F(0.25))
            ]
        );
        let e = FlatSchema::parse_ros2msg("m", "string name\n").unwrap_err();
        assert!(e.to_string().contains("type `string`"), "{e}");
    }
}
