//! GigE Vision cameras (the pure-Rust `gige` backend).

use std::time::Duration;

/// How to talk to the camera.
#[derive(Clone, Debug, PartialEq)]
pub struct GigeOptions {
    /// Per-request GVCP timeout.
    pub timeout: Duration,
    /// GVCP retries after a timeout.
    pub retries: u32,
    /// Stream packet size to ask for (SCPS, bytes with IP/UDP headers). Loopback carries
    /// jumbo packets; a real Ethernet link needs 1500 unless jumbo frames are enabled.
    pub packet_size: u32,
    /// Longest wait for a frame after the trigger.
    pub frame_timeout: Duration,
    /// Silence on the stream, once the frame has started, after which missing packets
    /// are asked again.
    pub packet_timeout: Duration,
    /// PACKETRESEND rounds before an incomplete frame is refused (0 = never resend).
    pub resend_rounds: u32,
    /// Heartbeat timeout to set on the camera (ms); None keeps the camera's.
    pub heartbeat_timeout_ms: Option<u32>,
}

impl Default for GigeOptions {
    fn default() -> Self {
        Self {
            timeout: Duration::from_millis(500),
            retries: 3,
            packet_size: 1500,
            frame_timeout: Duration::from_secs(10),
            packet_timeout: Duration::from_millis(100),
            resend_rounds: 3,
            heartbeat_timeout_ms: None,
        }
    }
}
