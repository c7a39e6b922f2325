//! A classic CAN 2.0 frame: fixed size, no heap, `Copy`, so it can cross lock-free
//! queues and be built in the control cycle.

/// Largest standard (11-bit) identifier.
pub const MAX_STANDARD_ID: u32 = 0x7FF;
/// Largest extended (29-bit) identifier.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

/// One classic CAN data frame (up to 8 data bytes).
#[derive(Clone, Copy, PartialEq, Eq, Default)]
pub struct CanFrame {
    /// Identifier (11 or 29 bit, see `extended`).
    pub id: u32,
    /// Data length code, 0..=8 (bytes).
    pub dlc: u8,
    /// Data; bytes beyond `dlc` are zero.
    pub data: [u8; 8],
    /// 29-bit identifier.
    pub extended: bool,
}

impl CanFrame {
    /// A standard-id frame from `data` (at most 8 bytes; `None` otherwise or if `id` > 0x7FF).
    pub fn new(id: u32, data: &[u8]) -> Option<CanFrame> {
        if id > MAX_STANDARD_ID || data.len() > 8 {
            return None;
        }
        let mut d = [0u8; 8];
        d[..data.len()].copy_from_slice(data);
        Some(CanFrame {
            id,
            dlc: data.len() as u8,
            data: d,
            extended: false,
        })
    }

    /// A standard-id frame from a fixed-size array (compile-time length ≤ 8; `id` masked to 11 bit).
    #[inline]
    pub fn std<const N: usize>(id: u16, bytes: [u8; N]) -> CanFrame {
        let mut d = [0u8; 8];
        let n = N.min(8);
        d[..n].copy_from_slice(&bytes[..n]);
        CanFrame {
            id: u32::from(id) & MAX_STANDARD_ID,
            dlc: n as u8,
            data: d,
            extended: false,
        }
    }

    /// The `dlc` valid data bytes.
    #[inline]
    pub fn payload(&self) -> &[u8] {
        &self.data[..usize::from(self.dlc.min(8))]
    }
}

impl std::fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.extended {
            write!(f, "{:08X} [{}]", self.id, self.dlc)?;
        } else {
            write!(f, "{:03X} [{}]", self.id, self.dlc)?;
        }
        for b in self.payload() {
            write!(f, " {b:02X}")?;
        }
        Ok(())
    }
}

/// Direction of a logged frame as seen by this process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Received from the bus.
    Rx,
    /// Sent to the bus.
    Tx,
}

impl Direction {
    /// "rx" or "tx".
    pub fn as_str(self) -> &'static str {
        match self {
            Direction::Rx => "rx",
            Direction::Tx => "tx",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn new_rejects_long_data_and_large_ids() {
        assert!(CanFrame::new(0x123, &[0; 9]).is_none());
        assert!(CanFrame::new(0x800, &[]).is_none());
        let f = CanFrame::new(0x7FF, &[1, 2, 3]).unwrap();
        assert_eq!(f.payload(), &[1, 2, 3]);
        assert_eq!(f.data[3..], [0; 5]);
    }

    #[test]
    fn debug_shows_three_digit_ids() {
        let f = CanFrame::std(0x80, []);
        assert_eq!(format!("{f:?}"), "080 [0]");
    }
}
