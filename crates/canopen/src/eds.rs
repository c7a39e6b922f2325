//! Electronic data sheets of the devices ehactl drives: CiA 306 EDS / DCF files (INI format),
//! parsed with the maintained `rust-ini` crate (case-insensitive sections and keys, as CiA 306
//! asks; no quote or backslash-escape processing, which CiA 306 does not have).
//!
//! What the start-up takes from a file ([`crate::startup`]): the identity it checks
//! (`[DeviceInfo]` VendorNumber / ProductNumber against 0x1018:01/02), the device type 0x1000
//! (profile number), which objects exist, their data type, access type (ro / const objects
//! are read and checked, never written) and PDO mappability, and, in a DCF, the
//! `ParameterValue` of each object, which is written (or, for ro / const, checked) at start-up
//! as a device-specific setting. Numbers follow CiA 306 §4.6.3: decimal, `0x` hexadecimal or
//! leading-`0` octal, optionally `$NODEID+` / `+$NODEID`.

use ini::{Ini, ParseOption};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The EDS of the project's simulated CiA 406 transducer (configs/eds), built in: used when
/// `canopen.transducer_eds` is empty.
pub const BUILTIN_TRANSDUCER_EDS: &str =
    include_str!("../../../configs/eds/ehactl_transducer_406.eds");
/// The EDS of the project's simulated CiA 408 valve (configs/eds), built in: used when
/// `canopen.valve_eds` is empty.
pub const BUILTIN_VALVE_EDS: &str = include_str!("../../../configs/eds/ehactl_valve_408.eds");

/// Access type of an object (CiA 306 `AccessType`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Read only (may change: process data).
    Ro,
    /// Write only.
    Wo,
    /// Read / write (`rw`, `rwr`, `rww`).
    Rw,
    /// Read only, constant.
    Const,
}

impl Access {
    /// Can be written by SDO.
    pub fn writable(self) -> bool {
        matches!(self, Access::Rw | Access::Wo)
    }
    /// Can be read by SDO.
    pub fn readable(self) -> bool {
        !matches!(self, Access::Wo)
    }
    /// As spelled in the EDS.
    pub fn as_str(self) -> &'static str {
        match self {
            Access::Ro => "ro",
            Access::Wo => "wo",
            Access::Rw => "rw",
            Access::Const => "const",
        }
    }
}

/// One object (a VAR, or one sub-index of an ARRAY / RECORD).
#[derive(Debug, Clone, PartialEq)]
pub struct EdsObject {
    /// `ParameterName`.
    pub name: String,
    /// CiA 301 data type index (0x0007 = UNSIGNED32, ...).
    pub data_type: u16,
    /// Access type.
    pub access: Access,
    /// `DefaultValue` (raw text).
    pub default: Option<String>,
    /// `ParameterValue` (DCF: the value to configure; raw text).
    pub parameter_value: Option<String>,
    /// `PDOMapping=1`.
    pub pdo_mapping: bool,
}

impl EdsObject {
    /// Size in bytes of the data type (None for strings / domains / unknown types).
    pub fn size(&self) -> Option<usize> {
        type_size(self.data_type)
    }
}

/// Size in bytes of a CiA 301 basic data type (table 44), None for strings and domains.
pub fn type_size(data_type: u16) -> Option<usize> {
    Some(match data_type {
        0x0001 | 0x0002 | 0x0005 => 1,
        0x0003 | 0x0006 => 2,
        0x0010 | 0x0016 => 3,
        0x0004 | 0x0007 | 0x0008 => 4,
        0x0012 | 0x0018 => 5,
        0x0013 | 0x0019 => 6,
        0x0014 | 0x001A => 7,
        0x0011 | 0x0015 | 0x001B => 8,
        _ => return None,
    })
}

/// A parsed EDS or DCF.
#[derive(Debug, Clone)]
pub struct Eds {
    /// Where it came from (path, or "built-in ..."), for messages.
    pub source: String,
    /// `[DeviceInfo]` VendorNumber.
    pub vendor: Option<u32>,
    /// `[DeviceInfo]` ProductNumber.
    pub product: Option<u32>,
    /// `[DeviceInfo]` RevisionNumber.
    pub revision: Option<u32>,
    /// `[DeviceInfo]` ProductName.
    pub product_name: Option<String>,
    /// `[DeviceComissioning]` NodeID (DCF only).
    pub dcf_node_id: Option<u8>,
    objects: BTreeMap<(u16, u8), EdsObject>,
}

/// Parse a CiA 306 number: decimal, `0x` hex, leading-`0` octal, optional `$NODEID` term.
pub fn parse_number(text: &str, node_id: u8) -> Result<i128, String> {
    let t = text.trim();
    let upper = t.to_ascii_uppercase();
    if let Some(pos) = upper.find("$NODEID") {
        let rest = format!("{}{}", &t[..pos], &t[pos + 7..]);
        let rest = rest.trim().trim_matches('+').trim();
        let v = if rest.is_empty() {
            0
        } else {
            parse_number(rest, node_id)?
        };
        return Ok(v + i128::from(node_id));
    }
    let (neg, body) = match t.strip_prefix('-') {
        Some(b) => (true, b.trim()),
        None => (false, t),
    };
    let v = if let Some(h) = body.strip_prefix("0x").or_else(|| body.strip_prefix("0X")) {
        i128::from_str_radix(h, 16)
    } else if body.len() > 1 && body.starts_with('0') {
        i128::from_str_radix(&body[1..], 8)
    } else {
        body.parse::<i128>()
    }
    .map_err(|_| format!("`{text}` is no CiA 306 number (decimal, 0x hex, 0 octal, $NODEID+n)"))?;
    Ok(if neg { -v } else { v })
}

fn parse_hex_index(s: &str) -> Option<u16> {
    (s.len() == 4)
        .then(|| u16::from_str_radix(s, 16).ok())
        .flatten()
}

/// The object of an EDS section name: `1018sub2` → (0x1018, 2), `1000` → (0x1000, 0);
/// `None` for the other sections ([DeviceInfo], …).
fn section_index(name: &str) -> Option<(u16, u8)> {
    let lower = name.to_ascii_lowercase();
    match lower.split_once("sub") {
        Some((i, s)) => Some((parse_hex_index(i)?, u8::from_str_radix(s, 16).ok()?)),
        None => Some((parse_hex_index(&lower)?, 0)),
    }
}

/// The object of section `[name]` (the CiA 306 object description keys): `None` for an ARRAY / RECORD
/// header (its sub-indices are their own sections), an error naming the key of a VAR
/// without a data type or with an unknown access type.
fn parse_object(
    source: &str,
    name: &str,
    props: &ini::Properties,
) -> Result<Option<EdsObject>, String> {
    let at = |k: &str| format!("{source}: [{name}] {k}");
    let object_type = match props.get("ObjectType") {
        Some(v) => parse_number(v, 0).map_err(|e| format!("{}: {e}", at("ObjectType")))?,
        None => 7,
    };
    if object_type != 7 {
        return Ok(None);
    }
    let data_type = props
        .get("DataType")
        .ok_or_else(|| format!("{} missing (a VAR needs its data type)", at("DataType")))
        .and_then(|v| {
            parse_number(v, 0)
                .ok()
                .and_then(|x| u16::try_from(x).ok())
                .ok_or_else(|| format!("{}={v}: expected a data type index", at("DataType")))
        })?;
    let access = match props
        .get("AccessType")
        .map(|a| a.trim().to_ascii_lowercase())
        .as_deref()
    {
        Some("ro") => Access::Ro,
        Some("wo") => Access::Wo,
        Some("rw" | "rwr" | "rww") => Access::Rw,
        Some("const") => Access::Const,
        other => {
            return Err(format!(
                "{}={}: expected ro, wo, rw, rwr, rww or const",
                at("AccessType"),
                other.unwrap_or("(missing)")
            ))
        }
    };
    let text = |k: &str| {
        props
            .get(k)
            .map(str::trim)
            .filter(|v| !v.is_empty())
            .map(str::to_string)
    };
    Ok(Some(EdsObject {
        name: props.get("ParameterName").unwrap_or("").to_string(),
        data_type,
        access,
        default: text("DefaultValue"),
        parameter_value: text("ParameterValue"),
        pdo_mapping: text("PDOMapping").is_some_and(|v| v != "0"),
    }))
}

impl Eds {
    /// Parse the text of an EDS / DCF; `source` names it in messages.
    pub fn parse(text: &str, source: &str) -> Result<Eds, String> {
        let opt = ParseOption {
            enabled_quote: false,
            enabled_escape: false,
            ..ParseOption::default()
        };
        let ini = Ini::load_from_str_opt(text, opt)
            .map_err(|e| format!("{source}: not an INI / EDS file: {e}"))?;
        let num = |sec: &str, key: &str| -> Result<Option<u32>, String> {
            match ini.get_from(Some(sec), key) {
                None => Ok(None),
                Some(v) => parse_number(v, 0)
                    .ok()
                    .and_then(|x| u32::try_from(x).ok())
                    .map(Some)
                    .ok_or_else(|| {
                        format!("{source}: [{sec}] {key}={v}: expected a 32-bit number")
                    }),
            }
        };
        let mut eds = Eds {
            source: source.to_string(),
            vendor: num("DeviceInfo", "VendorNumber")?,
            product: num("DeviceInfo", "ProductNumber")?,
            revision: num("DeviceInfo", "RevisionNumber")?,
            product_name: ini
                .get_from(Some("DeviceInfo"), "ProductName")
                .map(str::to_string),
            dcf_node_id: num("DeviceComissioning", "NodeID")?.map(|n| u8::try_from(n).unwrap_or(0)),
            objects: BTreeMap::new(),
        };
        for (name, props) in ini.iter() {
            let Some(name) = name else { continue };
            let Some(key) = section_index(name) else {
                continue;
            };
            if let Some(o) = parse_object(source, name, props)? {
                eds.objects.insert(key, o);
            }
        }
        if eds.objects.is_empty() {
            return Err(format!("{source}: no object sections ([1000], [1018sub1], ...); is this an EDS / DCF file?"));
        }
        Ok(eds)
    }

    /// Read and parse a file: a regular file of at most
    /// [`ehactl_input::EDS_MAX_BYTES`] (a FIFO or /dev/zero is refused, never read).
    pub fn load(path: &Path) -> Result<Eds, String> {
        let text =
            ehactl_input::read_bounded_string(path, ehactl_input::EDS_MAX_BYTES, "EDS / DCF")
                .map_err(|e| e.to_string())?;
        Eds::parse(&text, &path.display().to_string())
    }

    /// The file named in the config (`""` = the built-in EDS `builtin`), a relative path taken
    /// from `base` (the config file's directory).
    pub fn from_config(
        path: &str,
        base: Option<&Path>,
        builtin: &str,
        builtin_name: &str,
    ) -> Result<Eds, String> {
        if path.is_empty() {
            return Eds::parse(builtin, builtin_name);
        }
        let p = PathBuf::from(path);
        let p = match base {
            Some(b) if p.is_relative() => b.join(p),
            _ => p,
        };
        Eds::load(&p)
    }

    /// The object at `index:sub` (a VAR is at sub 0).
    pub fn get(&self, index: u16, sub: u8) -> Option<&EdsObject> {
        self.objects.get(&(index, sub))
    }

    /// Every object with a `ParameterValue` (DCF settings), in index order.
    pub fn parameter_values(&self) -> impl Iterator<Item = ((u16, u8), &EdsObject)> {
        self.objects
            .iter()
            .filter(|(_, o)| o.parameter_value.is_some())
            .map(|(k, o)| (*k, o))
    }

    /// A number of the file (`DefaultValue` / `ParameterValue`) as the object's bytes
    /// (little endian, the object's size); strings as their bytes.
    pub fn encode(&self, index: u16, sub: u8, text: &str, node_id: u8) -> Result<Vec<u8>, String> {
        let o = self
            .get(index, sub)
            .ok_or_else(|| format!("{}: no object 0x{index:04X}:{sub:02X}", self.source))?;
        match o.size() {
            Some(n) => {
                let v = parse_number(text, node_id).map_err(|e| {
                    format!("{}: 0x{index:04X}:{sub:02X} ({}): {e}", self.source, o.name)
                })?;
                let bits = 8 * n as u32;
                let signed = matches!(o.data_type, 0x02..=0x04 | 0x10 | 0x12..=0x15);
                let (lo, hi) = if signed {
                    (-(1i128 << (bits - 1)), (1i128 << bits) - 1) // hex may give the raw bits
                } else {
                    (0, (1i128 << bits) - 1)
                };
                if v < lo || v > hi {
                    return Err(format!(
                        "{}: 0x{index:04X}:{sub:02X} ({}) = {text} does not fit its {n}-byte data type",
                        self.source, o.name
                    ));
                }
                Ok((v as u128 as u64).to_le_bytes()[..n].to_vec())
            }
            None => Ok(text.as_bytes().to_vec()),
        }
    }

    /// The default value of a numeric object (None if absent or not a number).
    pub fn default_number(&self, index: u16, sub: u8, node_id: u8) -> Option<i128> {
        self.get(index, sub)?
            .default
            .as_deref()
            .and_then(|d| parse_number(d, node_id).ok())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_follow_cia306() {
        assert_eq!(parse_number("0x1A", 0).unwrap(), 26);
        assert_eq!(parse_number("017", 0).unwrap(), 15); // octal
        assert_eq!(parse_number("-5", 0).unwrap(), -5);
        assert_eq!(parse_number("$NODEID+0x180", 0x20).unwrap(), 0x1A0);
        assert_eq!(parse_number("0x200+$NodeId", 0x30).unwrap(), 0x230);
        assert!(parse_number("ten", 0).is_err());
    }

    #[test]
    fn the_shipped_files_parse_with_identity_and_access_types() {
        let t = Eds::parse(BUILTIN_TRANSDUCER_EDS, "t").unwrap();
        assert_eq!((t.vendor, t.product), (Some(0), Some(0x196)));
        assert_eq!(t.default_number(0x1000, 0, 32), Some(0x0008_0196));
        assert_eq!(t.get(0x1018, 1).unwrap().access, Access::Ro);
        assert_eq!(t.get(0x1008, 0).unwrap().access, Access::Const);
        assert_eq!(t.get(0x6005, 2).unwrap().data_type, 0x0007); // speed step (0x6005:02)
        assert!(t.get(0x6006, 1).is_none());
        assert!(t.get(0x6020, 1).unwrap().pdo_mapping);
        assert_eq!(t.default_number(0x1800, 1, 32), Some(0x1A0));
        let v = Eds::parse(BUILTIN_VALVE_EDS, "v").unwrap();
        assert_eq!(v.product, Some(0x198));
        assert_eq!(v.get(0x6041, 0).unwrap().access, Access::Ro);
        assert_eq!(v.encode(0x6300, 1, "-16384", 48).unwrap(), vec![0x00, 0xC0]);
        assert_eq!(
            v.encode(0x1400, 1, "$NODEID+0x200", 48).unwrap(),
            vec![0x30, 2, 0, 0]
        );
        assert!(v.encode(0x6042, 0, "300", 48).is_err());
        assert_eq!(v.parameter_values().count(), 0); // an EDS, not a DCF
    }

    #[test]
    fn sections_and_keys_are_case_insensitive_and_dcf_values_are_found() {
        let dcf = "[DEVICEINFO]\nvendornumber=0x2A\n[DeviceComissioning]\nNodeID=5\n\
                   [6200]\nparametername=Cyclic timer\nDataType=0x0006\naccesstype=RW\n\
                   DefaultValue=0\nParameterValue=10\n[1018SUB1]\nDataType=7\nAccessType=ro\n";
        let e = Eds::parse(dcf, "x.dcf").unwrap();
        assert_eq!((e.vendor, e.dcf_node_id), (Some(42), Some(5)));
        assert_eq!(e.get(0x1018, 1).unwrap().access, Access::Ro);
        let pv: Vec<_> = e.parameter_values().map(|(k, _)| k).collect();
        assert_eq!(pv, vec![(0x6200, 0)]);
        assert!(Eds::parse("[6200]\nDataType=6\nAccessType=maybe\n", "y").is_err());
        assert!(Eds::parse("just text\n", "z").is_err());
    }
}
