//! EMCY consumer (CiA 301 §7.2.7): 8-byte emergency messages on 0x080 + node id.

/// EMCY COB-ID base (+ node id).
pub const EMCY_BASE: u16 = 0x080;

/// A decoded emergency message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Emcy {
    /// Producer node id.
    pub node: u8,
    /// Emergency error code (CiA 301 Table 21); 0x0000 = error reset / no error.
    pub code: u16,
    /// Error register (object 0x1001).
    pub register: u8,
    /// Manufacturer-specific bytes.
    pub manufacturer: [u8; 5],
}

impl Emcy {
    /// Decode from the COB-ID's node id and the 8 data bytes; `Err` names a wrong DLC.
    pub fn parse(node: u8, data: &[u8]) -> Result<Emcy, usize> {
        if data.len() != 8 {
            return Err(data.len());
        }
        let mut m = [0u8; 5];
        m.copy_from_slice(&data[3..8]);
        Ok(Emcy {
            node,
            code: u16::from_le_bytes([data[0], data[1]]),
            register: data[2],
            manufacturer: m,
        })
    }

    /// True for "error reset or no error" (code 0x0000): not a fault.
    pub fn is_reset(&self) -> bool {
        self.code == 0
    }

    /// Error class of the code (CiA 301 Table 21, upper byte).
    pub fn class(&self) -> &'static str {
        code_class(self.code)
    }
}

/// CiA 301 Table 21 error code classes.
pub fn code_class(code: u16) -> &'static str {
    match code >> 8 {
        0x00 => "error reset or no error",
        0x10 => "generic error",
        0x20..=0x23 => "current",
        0x30..=0x33 => "voltage",
        0x40..=0x42 => "temperature",
        0x50 => "device hardware",
        0x60..=0x63 => "device software",
        0x70 => "additional modules",
        0x80..=0x82 => "monitoring / communication",
        0x90 => "external error",
        0xF0 => "additional functions",
        0xFF => "device specific",
        _ => "unknown error class",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_code_register_and_class() {
        let e = Emcy::parse(0x30, &[0x00, 0x50, 0x01, 0, 0, 0, 0, 0]).unwrap();
        assert_eq!((e.code, e.register), (0x5000, 0x01));
        assert_eq!(e.class(), "device hardware");
        assert!(!e.is_reset());
        assert!(Emcy::parse(0x30, &[0; 8]).unwrap().is_reset());
        assert_eq!(Emcy::parse(0x30, &[0; 3]), Err(3));
        assert_eq!(code_class(0x8130), "monitoring / communication");
    }
}
