//! GigE Vision, sans-IO: the control protocol (GVCP, [`gvcp`]) and the stream protocol
//! (GVSP, [`gvsp`]) as Aravis 0.8.26 and real cameras speak them, plus the bootstrap
//! register map ([`bootstrap`]) and pixel format codes ([`pfnc`]). All big-endian.

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

/// Bytes of IPv4 (20) + UDP (8) + GVSP standard header (8) that a stream packet size
/// (SCPS) includes besides the image data: every payload packet but the last carries
/// exactly `SCPS - 36` data bytes (Aravis places payload k at (k-1)*(SCPS-36)).
pub const GVSP_OVERHEAD: u32 = 36;

/// Parses a GenICam XML URL from the first/second URL register:
/// `Local:<file>;<hexaddr>;<hexsize>` (case-insensitive, optional `0x`). Returns
/// (file name, address, size). Other schemes (`File:`, `http:`) are `None`.
pub fn parse_local_url(raw: &[u8]) -> Option<(String, u32, u32)> {
    let end = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
    let s = std::str::from_utf8(&raw[..end]).ok()?.trim();
    if s.len() < 6 || !s[..6].eq_ignore_ascii_case("local:") {
        return None;
    }
    let mut parts = s[6..].split(';');
    let file = parts.next()?.trim().to_string();
    let hex = |t: &str| {
        let t = t.trim();
        let t = t
            .strip_prefix("0x")
            .or_else(|| t.strip_prefix("0X"))
            .unwrap_or(t);
        u32::from_str_radix(t, 16).ok()
    };
    let addr = hex(parts.next()?)?;
    // The size may be followed by `?SchemaVersion=...`.
    let size = hex(parts.next()?.split('?').next()?)?;
    Some((file, addr, size))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_urls_parse_like_aravis() {
        assert_eq!(
            parse_local_url(b"Local:arv-fake-camera.xml;10000;3a1f\0\0"),
            Some(("arv-fake-camera.xml".into(), 0x10000, 0x3a1f))
        );
        assert_eq!(
            parse_local_url(b"local:cam.zip;0x8000;0X100"),
            Some(("cam.zip".into(), 0x8000, 0x100))
        );
        assert_eq!(parse_local_url(b"http://x/cam.xml"), None);
        assert_eq!(parse_local_url(b"Local:cam.xml;zz;10"), None);
    }
}
