//! A minimal zip writer: stored (uncompressed) entries, which every unzip reads (PKWARE
//! APPNOTE.TXT 6.3.x, §4.3: local file headers, central directory, end of central
//! directory). An FMU is a zip file (FMI 2.0 §2.3); a few hundred kB of shared library and
//! text need no deflate, and the workspace has no zip crate to pull in for it.

/// The zip archive of `entries` (name, bytes), in the given order.
pub fn stored(entries: &[(&str, &[u8])]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let mut central = Vec::new();
    for (name, data) in entries {
        let size = u32::try_from(data.len()).map_err(|_| {
            format!(
                "{name}: {} bytes, over the 4 GiB of a zip entry",
                data.len()
            )
        })?;
        let offset = u32::try_from(out.len()).map_err(|_| "archive over 4 GiB".to_string())?;
        let crc = crc32fast::hash(data);
        let name_len = u16::try_from(name.len()).map_err(|_| format!("{name}: name too long"))?;
        // Local file header: version 2.0, no flags, stored, DOS time 1980-01-01 00:00.
        out.extend_from_slice(&0x0403_4b50u32.to_le_bytes());
        out.extend_from_slice(&20u16.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&0x0021u16.to_le_bytes());
        out.extend_from_slice(&crc.to_le_bytes());
        out.extend_from_slice(&size.to_le_bytes());
        out.extend_from_slice(&size.to_le_bytes());
        out.extend_from_slice(&name_len.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(name.as_bytes());
        out.extend_from_slice(data);
        // Central directory header; external attributes: a regular file, mode 0644.
        central.extend_from_slice(&0x0201_4b50u32.to_le_bytes());
        central.extend_from_slice(&0x031eu16.to_le_bytes());
        central.extend_from_slice(&20u16.to_le_bytes());
        central.extend_from_slice(&0u16.to_le_bytes());
        central.extend_from_slice(&0u16.to_le_bytes());
        central.extend_from_slice(&0u16.to_le_bytes());
        central.extend_from_slice(&0x0021u16.to_le_bytes());
        central.extend_from_slice(&crc.to_le_bytes());
        central.extend_from_slice(&size.to_le_bytes());
        central.extend_from_slice(&size.to_le_bytes());
        central.extend_from_slice(&name_len.to_le_bytes());
        central.extend_from_slice(&[0u8; 8]);
        central.extend_from_slice(&(0o100644u32 << 16).to_le_bytes());
        central.extend_from_slice(&offset.to_le_bytes());
        central.extend_from_slice(name.as_bytes());
    }
    let cd_offset = u32::try_from(out.len()).map_err(|_| "archive over 4 GiB".to_string())?;
    let cd_size = u32::try_from(central.len()).map_err(|_| "directory over 4 GiB".to_string())?;
    let n = u16::try_from(entries.len()).map_err(|_| "too many entries".to_string())?;
    out.extend_from_slice(&central);
    out.extend_from_slice(&0x0605_4b50u32.to_le_bytes());
    out.extend_from_slice(&[0u8; 4]);
    out.extend_from_slice(&n.to_le_bytes());
    out.extend_from_slice(&n.to_le_bytes());
    out.extend_from_slice(&cd_size.to_le_bytes());
    out.extend_from_slice(&cd_offset.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    Ok(out)
}

#[cfg(test)]
mod tests {
    /// The entries read back by walking the local headers as an unzip does (PKWARE
    /// APPNOTE §4.3.7), CRC-32 checked against an independent bitwise CRC (IEEE 802.3
    /// polynomial 0xEDB88320, the zip CRC).
    #[test]
    fn the_archive_reads_back_with_its_crcs() {
        fn crc(data: &[u8]) -> u32 {
            let mut c = !0u32;
            for &b in data {
                c ^= u32::from(b);
                for _ in 0..8 {
                    c = if c & 1 != 0 {
                        (c >> 1) ^ 0xEDB8_8320
                    } else {
                        c >> 1
                    };
                }
            }
            !c
        }
        let entries: [(&str, &[u8]); 2] = [("a.txt", b"hello"), ("b/c.bin", &[0, 1, 2, 255])];
        let z = super::stored(&entries).unwrap();
        let u16at = |i: usize| u16::from_le_bytes([z[i], z[i + 1]]) as usize;
        let u32at = |i: usize| u32::from_le_bytes([z[i], z[i + 1], z[i + 2], z[i + 3]]);
        let mut at = 0;
        for (name, data) in entries {
            assert_eq!(u32at(at), 0x0403_4b50);
            let (size, n) = (u32at(at + 18) as usize, u16at(at + 26));
            assert_eq!(&z[at + 30..at + 30 + n], name.as_bytes());
            let body = &z[at + 30 + n..at + 30 + n + size];
            assert_eq!(body, data);
            assert_eq!(u32at(at + 14), crc(data));
            at += 30 + n + size;
        }
        // the end record counts both entries and points at the central directory
        let end = z.len() - 22;
        assert_eq!(u32at(end), 0x0605_4b50);
        assert_eq!(u16at(end + 10), 2);
        assert_eq!(u32at(end + 16) as usize, at);
    }
}
