//! The one ZIP feature GigE Vision needs: many cameras store their GenICam XML as a
//! `.zip` holding one file. This reads the first entry through the central directory
//! (sizes there are valid even when the local header defers them to a data
//! descriptor), stored (method 0) or deflated (method 8), and checks its CRC-32.

fn u16le(b: &[u8], i: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(i..i + 2)?.try_into().ok()?))
}
fn u32le(b: &[u8], i: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(i..i + 4)?.try_into().ok()?))
}

/// CRC-32 (IEEE, reflected), as ZIP records it.
pub fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c ^= b as u32;
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

/// Largest file [`first_file`] inflates: [`super::MAX_XML_SIZE`] (GenICam XML files
/// are at most a few MB). A larger declared size is refused before inflating.
pub const MAX_UNCOMPRESSED: usize = super::MAX_XML_SIZE;

/// Why an archive from a camera was not read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ZipError {
    #[error("no ZIP end-of-central-directory record")]
    NoEndRecord,
    #[error("ZIP central directory not found at offset {0}, where its end record says")]
    NoDirectory(usize),
    #[error("truncated ZIP central directory entry at offset {0}")]
    TruncatedEntry(usize),
    #[error("ZIP entry `{name}`: no local header at offset {offset}")]
    NoLocalHeader { name: String, offset: usize },
    #[error("ZIP entry `{name}`: {size} bytes of data at offset {offset} run past the end of the {len}-byte archive")]
    DataPastEnd {
        name: String,
        offset: usize,
        size: usize,
        len: usize,
    },
    #[error("ZIP entry `{name}`: uncompressed size {size} bytes is more than the {max} bytes a GenICam XML may have (MAX_UNCOMPRESSED)")]
    TooLarge {
        name: String,
        size: usize,
        max: usize,
    },
    #[error("ZIP entry `{name}`: compression method {method} (only stored and deflate)")]
    Method { name: String, method: u16 },
    #[error("ZIP entry `{name}`: bad deflate data: {message}")]
    Deflate { name: String, message: String },
    #[error(
        "ZIP entry `{name}`: inflates to more than the {declared} bytes its directory declares"
    )]
    InflatesLarger { name: String, declared: usize },
    #[error("ZIP entry `{name}`: holds {got} bytes but its directory declares {declared} (corrupt download?)")]
    SizeMismatch {
        name: String,
        got: usize,
        declared: usize,
    },
    #[error("ZIP entry `{name}`: CRC-32 0x{got:08X} does not match the 0x{declared:08X} declared (corrupt download?)")]
    Crc {
        name: String,
        got: u32,
        declared: u32,
    },
}

/// The first file of a ZIP archive: (name, contents). Every offset and size in the
/// archive is checked against its length; the contents are at most
/// [`MAX_UNCOMPRESSED`] bytes, exactly as many as the directory declares, and never
/// inflated beyond that.
pub fn first_file(zip: &[u8]) -> Result<(String, Vec<u8>), ZipError> {
    // End of central directory: the last signature within 64 KiB + 22 of the end.
    let eocd = (0..zip.len().saturating_sub(21))
        .rev()
        .take(65_557)
        .find(|&i| u32le(zip, i) == Some(0x0605_4B50))
        .ok_or(ZipError::NoEndRecord)?;
    let cd = u32le(zip, eocd + 16).ok_or(ZipError::NoEndRecord)? as usize;
    if u32le(zip, cd) != Some(0x0201_4B50) {
        return Err(ZipError::NoDirectory(cd));
    }
    let bad = || ZipError::TruncatedEntry(cd);
    let method = u16le(zip, cd + 10).ok_or_else(bad)?;
    let crc = u32le(zip, cd + 16).ok_or_else(bad)?;
    let csize = u32le(zip, cd + 20).ok_or_else(bad)? as usize;
    let declared = u32le(zip, cd + 24).ok_or_else(bad)? as usize;
    let nlen = u16le(zip, cd + 28).ok_or_else(bad)? as usize;
    let local = u32le(zip, cd + 42).ok_or_else(bad)? as usize;
    let name_at = cd.checked_add(46).ok_or_else(bad)?;
    let name_end = name_at.checked_add(nlen).ok_or_else(bad)?;
    let name = String::from_utf8_lossy(zip.get(name_at..name_end).ok_or_else(bad)?).to_string();
    if u32le(zip, local) != Some(0x0403_4B50) {
        return Err(ZipError::NoLocalHeader {
            name,
            offset: local,
        });
    }
    let no_local = || ZipError::NoLocalHeader {
        name: name.clone(),
        offset: local,
    };
    let lnlen = u16le(zip, local + 26).ok_or_else(no_local)? as usize;
    let lxlen = u16le(zip, local + 28).ok_or_else(no_local)? as usize;
    let start = local.saturating_add(30 + lnlen + lxlen);
    let data = start
        .checked_add(csize)
        .and_then(|end| zip.get(start..end))
        .ok_or_else(|| ZipError::DataPastEnd {
            name: name.clone(),
            offset: start,
            size: csize,
            len: zip.len(),
        })?;
    if declared > MAX_UNCOMPRESSED {
        return Err(ZipError::TooLarge {
            name,
            size: declared,
            max: MAX_UNCOMPRESSED,
        });
    }
    let out = match method {
        0 => data.to_vec(),
        8 => match miniz_oxide::inflate::decompress_to_vec_with_limit(data, declared) {
            Ok(out) => out,
            Err(e) if e.status == miniz_oxide::inflate::TINFLStatus::HasMoreOutput => {
                return Err(ZipError::InflatesLarger { name, declared })
            }
            Err(e) => {
                return Err(ZipError::Deflate {
                    name,
                    message: format!("{:?}", e.status),
                })
            }
        },
        method => return Err(ZipError::Method { name, method }),
    };
    if out.len() != declared {
        return Err(ZipError::SizeMismatch {
            name,
            got: out.len(),
            declared,
        });
    }
    let got = crc32(&out);
    if got != crc {
        return Err(ZipError::Crc {
            name,
            got,
            declared: crc,
        });
    }
    Ok((name, out))
}

/// A one-file ZIP archive (for emulators and tests).
pub fn store_one(name: &str, data: &[u8], deflate: bool) -> Vec<u8> {
    let (method, body) = if deflate {
        (8u16, miniz_oxide::deflate::compress_to_vec(data, 6))
    } else {
        (0u16, data.to_vec())
    };
    let crc = crc32(data);
    let mut z = Vec::new();
    let common = |z: &mut Vec<u8>| {
        z.extend_from_slice(&20u16.to_le_bytes()); // version needed
        z.extend_from_slice(&0u16.to_le_bytes()); // flags
        z.extend_from_slice(&method.to_le_bytes());
        z.extend_from_slice(&[0, 0, 0x21, 0]); // time, date (1980-01-01)
        z.extend_from_slice(&crc.to_le_bytes());
        z.extend_from_slice(&(body.len() as u32).to_le_bytes());
        z.extend_from_slice(&(data.len() as u32).to_le_bytes());
        z.extend_from_slice(&(name.len() as u16).to_le_bytes());
        z.extend_from_slice(&0u16.to_le_bytes()); // extra length
    };
    z.extend_from_slice(&0x0403_4B50u32.to_le_bytes());
    common(&mut z);
    z.extend_from_slice(name.as_bytes());
    z.extend_from_slice(&body);
    let cd = z.len();
    z.extend_from_slice(&0x0201_4B50u32.to_le_bytes());
    z.extend_from_slice(&20u16.to_le_bytes()); // version made by
    common(&mut z);
    // comment length, disk start, internal and external attributes
    z.extend_from_slice(&[0; 10]);
    z.extend_from_slice(&0u32.to_le_bytes()); // local header offset
    z.extend_from_slice(name.as_bytes());
    let cd_len = z.len() - cd;
    z.extend_from_slice(&0x0605_4B50u32.to_le_bytes());
    z.extend_from_slice(&[0, 0, 0, 0, 1, 0, 1, 0]);
    z.extend_from_slice(&(cd_len as u32).to_le_bytes());
    z.extend_from_slice(&(cd as u32).to_le_bytes());
    z.extend_from_slice(&0u16.to_le_bytes());
    z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_the_standard_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn stored_and_deflated_archives_round_trip_and_corruption_is_caught() {
        let xml = include_bytes!("../../../config/gige/sim-camera.xml");
        for deflate in [false, true] {
            let z = store_one("cam.xml", xml, deflate);
            let (name, out) = first_file(&z).unwrap();
            assert_eq!(name, "cam.xml");
            assert_eq!(out, xml);
        }
        let mut z = store_one("cam.xml", xml, false);
        z[40] ^= 1;
        assert!(first_file(&z).unwrap_err().to_string().contains("CRC-32"));
        assert!(first_file(b"not a zip").is_err());
    }

    /// `store_one`'s archive with the declared uncompressed size replaced (local
    /// header at 22, central directory entry at `cd + 24`).
    fn declare_size(mut z: Vec<u8>, size: u32) -> Vec<u8> {
        let eocd = z.len() - 22;
        let cd = u32::from_le_bytes(z[eocd + 16..eocd + 20].try_into().unwrap()) as usize;
        z[22..26].copy_from_slice(&size.to_le_bytes());
        z[cd + 24..cd + 28].copy_from_slice(&size.to_le_bytes());
        z
    }

    #[test]
    fn zip_bombs_are_refused_by_their_declared_and_inflated_sizes() {
        let zeros = vec![0u8; 1 << 20];
        let z = store_one("cam.xml", &zeros, true);
        assert!(z.len() < 4 << 10, "{} bytes", z.len());
        // Declaring 17 MiB: more than any GenICam XML, refused before inflating.
        let e = first_file(&declare_size(z.clone(), 17 << 20))
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("17825792 bytes") && e.contains("16777216"),
            "{e}"
        );
        // Lying: declares 100 bytes, inflates to 1 MiB; stopped at the declared size.
        let e = first_file(&declare_size(z, 100))
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(e.contains("more than the 100 bytes"), "{e}");
        // Declares more than it inflates to.
        let z = store_one("cam.xml", b"<xml/>", true);
        let e = first_file(&declare_size(z, 1000))
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(e.contains("6 bytes") && e.contains("1000"), "{e}");
    }
}
