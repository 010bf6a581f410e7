//! The camera trait: grab a frame with its metadata.

use crate::error::DriverError;
use async_trait::async_trait;
use protocol::MonoImage;
use serde::Serialize;

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CameraInfo {
    pub model: String,
    pub serial: String,
    pub width: u32,
    pub height: u32,
    pub bit_depth: u8,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameMeta {
    /// Frame counter as the camera reports it.
    pub sequence: u64,
    /// Timestamp of the exposure start, nanoseconds, on the device's (or simulation's) clock.
    pub timestamp_ns: u64,
    pub exposure_us: f64,
    pub gain_db: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub image: MonoImage,
    pub meta: FrameMeta,
}

#[async_trait]
pub trait Camera: Send {
    fn info(&self) -> &CameraInfo;
    /// Expose and return one complete frame; an incomplete or corrupt frame is an error,
    /// never a frame.
    async fn grab(&mut self) -> Result<Frame, DriverError>;
}
