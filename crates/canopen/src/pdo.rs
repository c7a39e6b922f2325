//! PDOs (CiA 301 §7.2.2): mapping entries, the standard re-mapping procedure (written by
//! SDO at start-up, never in the cycle) and allocation-free packing / unpacking of mapped
//! values in the cycle.

/// TPDO1 COB-ID base (+ node id).
pub const TPDO1_BASE: u16 = 0x180;
/// RPDO1 COB-ID base (+ node id).
pub const RPDO1_BASE: u16 = 0x200;
/// RPDO1 communication parameter index.
pub const RPDO1_COMM: u16 = 0x1400;
/// RPDO1 mapping parameter index.
pub const RPDO1_MAP: u16 = 0x1600;
/// TPDO1 communication parameter index.
pub const TPDO1_COMM: u16 = 0x1800;
/// TPDO1 mapping parameter index.
pub const TPDO1_MAP: u16 = 0x1A00;
/// COB-ID bit 31: PDO does not exist / is not valid.
pub const COB_ID_INVALID: u32 = 0x8000_0000;
/// Transmission type 1: synchronous, every SYNC.
pub const TRANSMISSION_SYNC_EVERY: u8 = 1;

/// One mapped object: index, sub-index, length in bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapEntry {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Length (bits): 8, 16 or 32.
    pub bits: u8,
}

impl MapEntry {
    /// The mapping parameter value 0xIIIISSLL.
    pub fn encode(self) -> u32 {
        (u32::from(self.index) << 16) | (u32::from(self.sub) << 8) | u32::from(self.bits)
    }
}

/// A PDO mapping (at most 8 entries, at most 64 bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PdoMap {
    entries: [MapEntry; 8],
    n: usize,
}

impl PdoMap {
    /// Number of mapped entries.
    pub fn count(&self) -> usize {
        self.n
    }

    /// Mapping from `entries`; `None` if more than 8 entries or more than 8 bytes.
    pub fn new(entries: &[MapEntry]) -> Option<PdoMap> {
        let bits: u32 = entries.iter().map(|e| u32::from(e.bits)).sum();
        if entries.len() > 8 || bits > 64 || entries.iter().any(|e| e.bits % 8 != 0 || e.bits == 0)
        {
            return None;
        }
        let mut m = PdoMap {
            entries: [MapEntry {
                index: 0,
                sub: 0,
                bits: 0,
            }; 8],
            n: entries.len(),
        };
        m.entries[..entries.len()].copy_from_slice(entries);
        Some(m)
    }

    /// The entries.
    pub fn entries(&self) -> &[MapEntry] {
        &self.entries[..self.n]
    }

    /// Payload length (bytes).
    pub fn len_bytes(&self) -> usize {
        self.entries().iter().map(|e| usize::from(e.bits / 8)).sum()
    }

    /// Byte offset of entry `i`.
    pub fn offset(&self, i: usize) -> usize {
        self.entries[..i]
            .iter()
            .map(|e| usize::from(e.bits / 8))
            .sum()
    }
}

/// One SDO write of the configuration sequence: object, sub-index, value, size (bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SdoWrite {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Value (little-endian on the wire).
    pub value: u32,
    /// Size (bytes): 1, 2 or 4.
    pub size: u8,
}

impl SdoWrite {
    /// The value's bytes.
    pub fn bytes(&self) -> ([u8; 4], usize) {
        (self.value.to_le_bytes(), usize::from(self.size))
    }
}

/// The CiA 301 re-mapping procedure for one PDO: (1) invalidate (COB-ID bit 31),
/// (2) transmission type, (3) mapping count 0, (4) entries, (5) count n, (6) valid COB-ID.
pub fn remap_sequence(
    comm_index: u16,
    map_index: u16,
    cob_id: u16,
    transmission_type: u8,
    map: &PdoMap,
) -> Vec<SdoWrite> {
    let w = |index, sub, value, size| SdoWrite {
        index,
        sub,
        value,
        size,
    };
    let mut v = vec![
        w(comm_index, 1, COB_ID_INVALID | u32::from(cob_id), 4),
        w(comm_index, 2, u32::from(transmission_type), 1),
        w(map_index, 0, 0, 1),
    ];
    for (i, e) in map.entries().iter().enumerate() {
        v.push(w(map_index, (i + 1) as u8, e.encode(), 4));
    }
    v.push(w(map_index, 0, map.n as u32, 1));
    v.push(w(comm_index, 1, u32::from(cob_id), 4));
    v
}

/// Read a little-endian signed value of `bytes` bytes at `off` (sign-extended).
#[inline]
pub fn get_i32(data: &[u8], off: usize, bytes: usize) -> i32 {
    match bytes {
        1 => i32::from(data[off] as i8),
        2 => i32::from(i16::from_le_bytes([data[off], data[off + 1]])),
        _ => i32::from_le_bytes([data[off], data[off + 1], data[off + 2], data[off + 3]]),
    }
}

/// Read a little-endian unsigned 16-bit value at `off`.
#[inline]
pub fn get_u16(data: &[u8], off: usize) -> u16 {
    u16::from_le_bytes([data[off], data[off + 1]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mapping_entries_encode_as_iiiissll() {
        let e = MapEntry {
            index: 0x6020,
            sub: 1,
            bits: 32,
        };
        assert_eq!(e.encode(), 0x6020_0120);
        assert_eq!(
            MapEntry {
                index: 0x6041,
                sub: 0,
                bits: 16
            }
            .encode(),
            0x6041_0010
        );
    }

    #[test]
    fn remap_follows_the_cia301_procedure() {
        let map = PdoMap::new(&[
            MapEntry {
                index: 0x6041,
                sub: 0,
                bits: 16,
            },
            MapEntry {
                index: 0x6301,
                sub: 1,
                bits: 16,
            },
        ])
        .unwrap();
        assert_eq!(map.len_bytes(), 4);
        assert_eq!(map.offset(1), 2);
        let s = remap_sequence(TPDO1_COMM, TPDO1_MAP, 0x1B0, 1, &map);
        let v: Vec<(u16, u8, u32)> = s.iter().map(|w| (w.index, w.sub, w.value)).collect();
        assert_eq!(
            v,
            vec![
                (0x1800, 1, 0x8000_01B0),
                (0x1800, 2, 1),
                (0x1A00, 0, 0),
                (0x1A00, 1, 0x6041_0010),
                (0x1A00, 2, 0x6301_0110),
                (0x1A00, 0, 2),
                (0x1800, 1, 0x0000_01B0),
            ]
        );
    }

    #[test]
    fn rejects_oversized_maps_and_sign_extends() {
        let e = MapEntry {
            index: 0x6020,
            sub: 1,
            bits: 32,
        };
        assert!(PdoMap::new(&[e, e, e]).is_none());
        assert!(PdoMap::new(&[MapEntry { bits: 12, ..e }]).is_none());
        assert_eq!(get_i32(&[0xFF, 0xFF, 0xFF, 0xFF], 0, 4), -1);
        assert_eq!(get_i32(&[0x00, 0xC0], 0, 2), -16384);
        assert_eq!(get_u16(&[0x37, 0x02], 0), 0x0237);
    }
}
