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

/// The first file of a ZIP archive: (name, contents).
pub fn first_file(zip: &[u8]) -> Result<(String, Vec<u8>), String> {
    // End of central directory: the last signature within 64 KiB + 22 of the end.
    let eocd = (0..zip.len().saturating_sub(21))
        .rev()
        .take(65_557)
        .find(|&i| u32le(zip, i) == Some(0x0605_4B50))
        .ok_or("no ZIP end-of-central-directory record")?;
    let cd = u32le(zip, eocd + 16).ok_or("truncated ZIP directory")? as usize;
    if u32le(zip, cd) != Some(0x0201_4B50) {
        return Err("ZIP central directory not found where its end record says".into());
    }
    let bad = || "truncated ZIP central directory entry".to_string();
    let method = u16le(zip, cd + 10).ok_or_else(bad)?;
    let crc = u32le(zip, cd + 16).ok_or_else(bad)?;
    let csize = u32le(zip, cd + 20).ok_or_else(bad)? as usize;
    let usize_ = u32le(zip, cd + 24).ok_or_else(bad)? as usize;
    let nlen = u16le(zip, cd + 28).ok_or_else(bad)? as usize;
    let local = u32le(zip, cd + 42).ok_or_else(bad)? as usize;
    let name =
        String::from_utf8_lossy(zip.get(cd + 46..cd + 46 + nlen).ok_or_else(bad)?).to_string();
    if u32le(zip, local) != Some(0x0403_4B50) {
        return Err(format!("ZIP entry `{name}`: no local header at {local}"));
    }
    let lnlen = u16le(zip, local + 26).ok_or_else(bad)? as usize;
    let lxlen = u16le(zip, local + 28).ok_or_else(bad)? as usize;
    let start = local + 30 + lnlen + lxlen;
    let data = zip
        .get(start..start + csize)
        .ok_or_else(|| format!("ZIP entry `{name}`: data runs past the end"))?;
    let out = match method {
        0 => data.to_vec(),
        8 => miniz_oxide::inflate::decompress_to_vec(data)
            .map_err(|e| format!("ZIP entry `{name}`: bad deflate data: {e:?}"))?,
        m => {
            return Err(format!(
                "ZIP entry `{name}`: compression method {m} (only stored and deflate)"
            ))
        }
    };
    if out.len() != usize_ || crc32(&out) != crc {
        return Err(format!(
            "ZIP entry `{name}`: size or CRC-32 does not match (corrupt download?)"
        ));
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
        assert!(first_file(&z).unwrap_err().contains("CRC-32"));
        assert!(first_file(b"not a zip").is_err());
    }
}
