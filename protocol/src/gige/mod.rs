//! GigE Vision, sans-IO: the control protocol (GVCP, [`gvcp`]) and the stream protocol
//! (GVSP, [`gvsp`]) as Aravis 0.8.26 and real cameras speak them, plus the bootstrap
//! register map ([`bootstrap`]) and pixel format codes ([`pfnc`]). All big-endian.

#[cfg(test)]
mod fuzz;
pub mod gvcp;
pub mod gvsp;
pub mod zip;

/// Bootstrap register addresses (GigE Vision 2.x, section "bootstrap registers").
pub mod bootstrap {
    pub const VERSION: u32 = 0x0000;
    pub const DEVICE_MODE: u32 = 0x0004;
    pub const MAC_HIGH: u32 = 0x0008;
    pub const MAC_LOW: u32 = 0x000C;
    pub const IP_CONFIG_SUPPORTED: u32 = 0x0010;
    pub const IP_CONFIG_CURRENT: u32 = 0x0014;
    pub const CURRENT_IP: u32 = 0x0024;
    pub const SUBNET_MASK: u32 = 0x0034;
    pub const DEFAULT_GATEWAY: u32 = 0x0044;
    /// 32-byte string.
    pub const MANUFACTURER: u32 = 0x0048;
    /// 32-byte string.
    pub const MODEL: u32 = 0x0068;
    /// 32-byte string.
    pub const DEVICE_VERSION: u32 = 0x0088;
    /// 48-byte string.
    pub const MANUFACTURER_INFO: u32 = 0x00A8;
    /// 16-byte string.
    pub const SERIAL_NUMBER: u32 = 0x00D8;
    /// 16-byte string.
    pub const USER_NAME: u32 = 0x00E8;
    /// Length of the discovery ack payload (registers 0x0000..0x00F8).
    pub const DISCOVERY_LEN: usize = 0xF8;
    /// 512-byte string `Local:<file>;<addr hex>;<size hex>`.
    pub const FIRST_URL: u32 = 0x0200;
    pub const SECOND_URL: u32 = 0x0400;
    pub const URL_LEN: usize = 512;
    pub const NUM_NETWORK_INTERFACES: u32 = 0x0600;
    pub const NUM_MESSAGE_CHANNELS: u32 = 0x0900;
    pub const NUM_STREAM_CHANNELS: u32 = 0x0904;
    pub const STREAM_CHANNEL_CAPS: u32 = 0x092C;
    pub const GVCP_CAPABILITY: u32 = 0x0934;
    pub const HEARTBEAT_TIMEOUT: u32 = 0x0938;
    pub const TICK_FREQUENCY_HIGH: u32 = 0x093C;
    pub const TICK_FREQUENCY_LOW: u32 = 0x0940;
    pub const GVCP_CONFIG: u32 = 0x0954;
    pub const GVSP_CONFIG: u32 = 0x0960;
    /// Control channel privilege.
    pub const CCP: u32 = 0x0A00;
    /// Stream channel 0 port (bits 15-0 host port; 0 = closed).
    pub const SCP0: u32 = 0x0D00;
    /// Stream channel 0 packet size (bits 15-0, bytes including IP and UDP headers).
    pub const SCPS0: u32 = 0x0D04;
    pub const SCPD0: u32 = 0x0D08;
    /// Stream channel 0 destination IPv4 address.
    pub const SCDA0: u32 = 0x0D18;
    /// Stream channel 0 source UDP port (read-only).
    pub const SCSP0: u32 = 0x0D1C;

    /// CCP bits.
    pub const CCP_EXCLUSIVE: u32 = 0x1;
    pub const CCP_CONTROL: u32 = 0x2;
    /// GVCP capability bits.
    pub const CAP_WRITEMEM: u32 = 0x2;
    pub const CAP_PACKETRESEND: u32 = 0x4;
    /// GVCP configuration bit: heartbeat disabled.
    pub const GVCP_CONFIG_HEARTBEAT_DISABLE: u32 = 0x1;
}

/// Pixel Format Naming Convention codes (bits 23-16: bits per pixel).
pub mod pfnc {
    pub const MONO8: u32 = 0x0108_0001;
    pub const MONO16: u32 = 0x0110_0007;

    /// Bits per pixel of a PFNC code.
    pub fn bits_per_pixel(code: u32) -> u32 {
        (code >> 16) & 0xFF
    }

    /// Name of the formats this crate decodes, for error messages.
    pub fn name(code: u32) -> String {
        match code {
            MONO8 => "Mono8".into(),
            MONO16 => "Mono16".into(),
            other => format!("pixel format 0x{other:08X}"),
        }
    }
}

/// Largest GenICam XML read from a camera, zipped or not: 16 MiB (GenICam XML files
/// are at most a few MB). A URL register or an archive declaring more is refused
/// before anything is read or inflated.
pub const MAX_XML_SIZE: usize = 16 << 20;

/// Bytes of IPv4 (20) + UDP (8) + GVSP standard header (8) that a stream packet size
/// (SCPS) includes besides the image data: every payload packet but the last carries
/// exactly `SCPS - 36` data bytes (Aravis places payload k at (k-1)*(SCPS-36)).
pub const GVSP_OVERHEAD: u32 = 36;

/// Why a URL register does not name GenICam XML this crate can read. The register is
/// 512 bytes of whatever the camera holds: nothing in it is trusted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UrlError {
    #[error("GenICam XML URL is not text: byte 0x{byte:02X} at offset {at} is not UTF-8")]
    NotText { at: usize, byte: u8 },
    #[error(
        "GenICam XML URL `{0}` is not a `Local:` URL (only XML in the camera's own memory is read)"
    )]
    NotLocal(String),
    #[error("GenICam XML URL `{url}`: the {field} is missing (expected `Local:<file>;<hex address>;<hex size>`)")]
    Missing { url: String, field: &'static str },
    #[error("GenICam XML URL `{url}`: {field} `{value}` is not a 32-bit hexadecimal number")]
    BadHex {
        url: String,
        field: &'static str,
        value: String,
    },
}

/// Parses a GenICam XML URL from the first/second URL register:
/// `Local:<file>;<hexaddr>;<hexsize>` (case-insensitive, optional `0x`). Returns
/// (file name, address, size). Other schemes (`File:`, `http:`) and anything
/// malformed (bytes that are not UTF-8 included) are errors naming what was wrong.
pub fn parse_local_url(raw: &[u8]) -> Result<(String, u32, u32), UrlError> {
    let end = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
    let s = std::str::from_utf8(&raw[..end])
        .map_err(|e| UrlError::NotText {
            at: e.valid_up_to(),
            byte: raw[e.valid_up_to()],
        })?
        .trim();
    // Compared as bytes: the text may hold multi-byte characters anywhere.
    let rest = match s.as_bytes().get(..6) {
        Some(scheme) if scheme.eq_ignore_ascii_case(b"local:") => &s[6..],
        _ => return Err(UrlError::NotLocal(s.to_string())),
    };
    let missing = |field| UrlError::Missing {
        url: s.to_string(),
        field,
    };
    let mut parts = rest.split(';');
    let file = parts.next().map(str::trim).unwrap_or_default();
    if file.is_empty() {
        return Err(missing("file name"));
    }
    let hex = |field, t: &str| {
        let t = t.trim();
        let digits = t
            .strip_prefix("0x")
            .or_else(|| t.strip_prefix("0X"))
            .unwrap_or(t);
        u32::from_str_radix(digits, 16).map_err(|_| UrlError::BadHex {
            url: s.to_string(),
            field,
            value: t.to_string(),
        })
    };
    let addr = hex("address", parts.next().ok_or_else(|| missing("address"))?)?;
    // The size may be followed by `?SchemaVersion=...`.
    let size_text = parts.next().ok_or_else(|| missing("size"))?;
    let size = hex("size", size_text.split('?').next().unwrap_or_default())?;
    Ok((file.to_string(), addr, size))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_urls_parse_like_aravis() {
        assert_eq!(
            parse_local_url(b"Local:arv-fake-camera.xml;10000;3a1f\0\0"),
            Ok(("arv-fake-camera.xml".into(), 0x10000, 0x3a1f))
        );
        assert_eq!(
            parse_local_url(b"local:cam.zip;0x8000;0X100"),
            Ok(("cam.zip".into(), 0x8000, 0x100))
        );
        assert_eq!(
            parse_local_url(b"http://x/cam.xml"),
            Err(UrlError::NotLocal("http://x/cam.xml".into()))
        );
        assert_eq!(
            parse_local_url(b"Local:cam.xml;zz;10").unwrap_err().to_string(),
            "GenICam XML URL `Local:cam.xml;zz;10`: address `zz` is not a 32-bit hexadecimal number"
        );
        assert!(parse_local_url(b"Local:cam.xml;0;123456789")
            .unwrap_err()
            .to_string()
            .contains("size `123456789`"));
        assert!(matches!(
            parse_local_url(b"Local:cam.xml;10"),
            Err(UrlError::Missing { field: "size", .. })
        ));
    }

    #[test]
    fn non_ascii_urls_are_errors_not_panics() {
        // Byte 6 inside a two-byte character: slicing the scheme there used to panic.
        for raw in [
            "Locaé:cam.xml;0;10".as_bytes(),
            "Localé:cam.xml;0;10".as_bytes(),
            "éééé".as_bytes(),
            b"Local\xFF:cam.xml;0;10",
            &[0xC3, 0xA9, 0xC3, 0xA9, 0xC3, 0xA9, 0xC3],
        ] {
            let r = std::panic::catch_unwind(|| parse_local_url(raw));
            assert!(r.expect("no panic").is_err(), "{raw:?}");
        }
        assert_eq!(
            parse_local_url(b"Local\xFF:cam.xml;0;10"),
            Err(UrlError::NotText { at: 5, byte: 0xFF })
        );
        // Multi-byte characters after the scheme are text like any other.
        assert_eq!(
            parse_local_url("Local:caméra.xml;8000;10".as_bytes()),
            Ok(("caméra.xml".into(), 0x8000, 0x10))
        );
    }
}
