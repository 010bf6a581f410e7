//! GVSP: the GigE Vision stream protocol, for images (leader, payload packets, trailer)
//! with the standard 8-byte header and 16-bit block ids. [`packetize`] cuts a frame the
//! way a camera sends it; [`Assembler`] puts it back together and says exactly which
//! packets are missing, so an incomplete frame is never mistaken for a complete one.

use super::gvcp::{get16, get32, put16, put32};
use super::{pfnc, GVSP_OVERHEAD};

pub const FORMAT_LEADER: u8 = 1;
pub const FORMAT_TRAILER: u8 = 2;
pub const FORMAT_PAYLOAD: u8 = 3;
/// Payload type "image".
pub const PAYLOAD_IMAGE: u16 = 0x0001;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GvspError {
    #[error("GVSP packet of {0} bytes is too short")]
    Short(usize),
    #[error("GVSP packet uses the extended-id header (64-bit block ids), which this codec does not decode")]
    ExtendedId,
    #[error("GVSP packet format {0} is not leader, payload or trailer")]
    Format(u8),
    #[error("GVSP leader payload type 0x{0:04X} is not an image")]
    PayloadType(u16),
    #[error("GVSP leader: width {width} x height {height} at {bits} bit is {bytes} bytes, more than the {negotiated}-byte payload negotiated at open")]
    LeaderTooLarge {
        width: u32,
        height: u32,
        bits: u32,
        bytes: u128,
        negotiated: usize,
    },
    #[error("GVSP leader: {got}, but {negotiated} was negotiated at open")]
    LeaderMismatch { got: String, negotiated: String },
    #[error("stream format: width {width} x height {height} at {bits} bit is {bytes} bytes; a frame must hold 1 to {max} bytes (MAX_PAYLOAD_SIZE)")]
    FrameSize {
        width: u32,
        height: u32,
        bits: u32,
        bytes: u128,
        max: usize,
    },
}

/// Largest frame an [`Assembler`] holds: 512 MiB, a 16384 x 16384 Mono16 sensor. A
/// camera declaring more at open is refused rather than trusted with the memory.
pub const MAX_PAYLOAD_SIZE: usize = 512 << 20;

/// Bytes of `width` x `height` pixels at `bits` per pixel, in u128 (cannot overflow).
fn frame_bytes(width: u32, height: u32, bits: u32) -> u128 {
    width as u128 * height as u128 * bits as u128 / 8
}

/// `1280x1024 Mono8`, for error messages.
fn describe(width: u32, height: u32, pixel_format: u32) -> String {
    format!("{width}x{height} {}", pfnc::name(pixel_format))
}

/// What was negotiated with the camera at open. Every leader must match it; nothing a
/// packet says is allocated beyond it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Negotiated {
    pub width: u32,
    pub height: u32,
    pub pixel_format: u32,
    /// Bytes of image data per frame (width x height x bits per pixel / 8).
    pub payload_size: usize,
}

impl Negotiated {
    /// The stream format read from the camera at open; refused if a frame of it would
    /// be empty or larger than [`MAX_PAYLOAD_SIZE`].
    pub fn new(width: u32, height: u32, pixel_format: u32) -> Result<Self, GvspError> {
        let bits = pfnc::bits_per_pixel(pixel_format);
        let bytes = frame_bytes(width, height, bits);
        if bytes == 0 || bytes > MAX_PAYLOAD_SIZE as u128 {
            return Err(GvspError::FrameSize {
                width,
                height,
                bits,
                bytes,
                max: MAX_PAYLOAD_SIZE,
            });
        }
        Ok(Self {
            width,
            height,
            pixel_format,
            payload_size: bytes as usize,
        })
    }

    /// Whether `l` describes a frame of this format; the size is checked first, so a
    /// spoofed or corrupt leader never drives an allocation.
    pub fn check(&self, l: &ImageLeader) -> Result<usize, GvspError> {
        let bits = pfnc::bits_per_pixel(l.pixel_format);
        let bytes = frame_bytes(l.width, l.height, bits);
        if bytes > self.payload_size as u128 {
            return Err(GvspError::LeaderTooLarge {
                width: l.width,
                height: l.height,
                bits,
                bytes,
                negotiated: self.payload_size,
            });
        }
        if (l.width, l.height, l.pixel_format) != (self.width, self.height, self.pixel_format) {
            return Err(GvspError::LeaderMismatch {
                got: describe(l.width, l.height, l.pixel_format),
                negotiated: describe(self.width, self.height, self.pixel_format),
            });
        }
        Ok(bytes as usize)
    }
}

/// Image leader: what the payload packets of a block will hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageLeader {
    /// Device timestamp in ticks.
    pub timestamp: u64,
    pub pixel_format: u32,
    pub width: u32,
    pub height: u32,
    pub offset_x: u32,
    pub offset_y: u32,
}

impl ImageLeader {
    /// Bytes of image data the block carries (saturating at `usize::MAX`: a leader
    /// is outside input; [`Negotiated::check`] is what bounds it).
    pub fn payload_size(&self) -> usize {
        let bytes = frame_bytes(
            self.width,
            self.height,
            pfnc::bits_per_pixel(self.pixel_format),
        );
        usize::try_from(bytes).unwrap_or(usize::MAX)
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Content<'a> {
    Leader(ImageLeader),
    Payload(&'a [u8]),
    Trailer { size_y: u32 },
}

/// One decoded stream packet (borrowing the datagram).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet<'a> {
    pub status: u16,
    pub block_id: u16,
    pub packet_id: u32,
    pub content: Content<'a>,
}

fn header(out: &mut Vec<u8>, status: u16, block_id: u16, format: u8, packet_id: u32) {
    put16(out, status);
    put16(out, block_id);
    out.push(format & 0x7F);
    let p = packet_id.to_be_bytes();
    out.extend_from_slice(&p[1..4]);
}

impl Packet<'_> {
    pub fn encode(&self, out: &mut Vec<u8>) {
        match &self.content {
            Content::Leader(l) => {
                header(
                    out,
                    self.status,
                    self.block_id,
                    FORMAT_LEADER,
                    self.packet_id,
                );
                put16(out, 0);
                put16(out, PAYLOAD_IMAGE);
                put32(out, (l.timestamp >> 32) as u32);
                put32(out, l.timestamp as u32);
                put32(out, l.pixel_format);
                put32(out, l.width);
                put32(out, l.height);
                put32(out, l.offset_x);
                put32(out, l.offset_y);
                put16(out, 0);
                put16(out, 0);
            }
            Content::Payload(d) => {
                header(
                    out,
                    self.status,
                    self.block_id,
                    FORMAT_PAYLOAD,
                    self.packet_id,
                );
                out.extend_from_slice(d);
            }
            Content::Trailer { size_y } => {
                header(
                    out,
                    self.status,
                    self.block_id,
                    FORMAT_TRAILER,
                    self.packet_id,
                );
                put16(out, 0);
                put16(out, PAYLOAD_IMAGE);
                put32(out, *size_y);
            }
        }
    }

    pub fn decode(b: &[u8]) -> Result<Packet<'_>, GvspError> {
        if b.len() < 8 {
            return Err(GvspError::Short(b.len()));
        }
        if b[4] & 0x80 != 0 {
            return Err(GvspError::ExtendedId);
        }
        let status = get16(b, 0);
        let block_id = get16(b, 2);
        let format = b[4] & 0x7F;
        let packet_id = u32::from_be_bytes([0, b[5], b[6], b[7]]);
        let p = &b[8..];
        let content = match format {
            FORMAT_LEADER => {
                if p.len() < 36 {
                    return Err(GvspError::Short(b.len()));
                }
                let pt = get16(p, 2);
                if pt != PAYLOAD_IMAGE {
                    return Err(GvspError::PayloadType(pt));
                }
                Content::Leader(ImageLeader {
                    timestamp: ((get32(p, 4) as u64) << 32) | get32(p, 8) as u64,
                    pixel_format: get32(p, 12),
                    width: get32(p, 16),
                    height: get32(p, 20),
                    offset_x: get32(p, 24),
                    offset_y: get32(p, 28),
                })
            }
            FORMAT_PAYLOAD => Content::Payload(p),
            FORMAT_TRAILER => {
                if p.len() < 8 {
                    return Err(GvspError::Short(b.len()));
                }
                Content::Trailer {
                    size_y: get32(p, 4),
                }
            }
            other => return Err(GvspError::Format(other)),
        };
        Ok(Packet {
            status,
            block_id,
            packet_id,
            content,
        })
    }
}

/// Data bytes per payload packet for a stream packet size (SCPS).
pub fn chunk_size(packet_size: u32) -> usize {
    packet_size.saturating_sub(GVSP_OVERHEAD).max(4) as usize
}

/// Number of payload packets of a frame (saturating at `u32::MAX`).
pub fn payload_packets(payload_size: usize, packet_size: u32) -> u32 {
    u32::try_from(payload_size.div_ceil(chunk_size(packet_size))).unwrap_or(u32::MAX)
}

/// Encodes packet `packet_id` (0 = leader, 1..=N payload, N+1 trailer) of a frame into
/// `out` (cleared first). Used for the first transmission and for resends alike.
/// Returns false if `packet_id` is beyond the trailer.
pub fn encode_frame_packet(
    block_id: u16,
    leader: &ImageLeader,
    data: &[u8],
    packet_size: u32,
    packet_id: u32,
    out: &mut Vec<u8>,
) -> bool {
    out.clear();
    let chunk = chunk_size(packet_size);
    let n = payload_packets(data.len(), packet_size);
    let content = if packet_id == 0 {
        Content::Leader(*leader)
    } else if packet_id <= n {
        let start = (packet_id as usize - 1) * chunk;
        Content::Payload(&data[start..(start + chunk).min(data.len())])
    } else if packet_id == n + 1 {
        Content::Trailer {
            size_y: leader.height,
        }
    } else {
        return false;
    };
    Packet {
        status: 0,
        block_id,
        packet_id,
        content,
    }
    .encode(out);
    true
}

/// Reassembles one block from its packets, in any order. Sizes come from what was
/// negotiated at open, never from a packet: a leader that does not match is refused
/// before anything is allocated, and payload packets are placed with checked
/// arithmetic.
#[derive(Debug, Clone)]
pub struct Assembler {
    pub block_id: u16,
    pub leader: Option<ImageLeader>,
    negotiated: Negotiated,
    chunk: usize,
    data: Vec<u8>,
    received: Vec<bool>,
    trailer_seen: bool,
    /// Packets whose size or position did not fit the leader (a corrupt stream).
    pub malformed: u32,
}

impl Assembler {
    /// `packet_size` is the SCPS the device was told to use; `negotiated` the stream
    /// format read from the camera at open.
    pub fn new(block_id: u16, packet_size: u32, negotiated: Negotiated) -> Self {
        Self {
            block_id,
            leader: None,
            negotiated,
            chunk: chunk_size(packet_size),
            data: Vec::new(),
            received: Vec::new(),
            trailer_seen: false,
            malformed: 0,
        }
    }

    /// The stream format this block must have.
    pub fn negotiated(&self) -> &Negotiated {
        &self.negotiated
    }

    /// Takes one packet of this block (others are ignored; returns whether it was
    /// used). A leader that does not match what was negotiated is an error (the frame
    /// cannot be assembled); a payload packet of the wrong size or position is counted
    /// in [`Assembler::malformed`] and dropped.
    pub fn push(&mut self, p: &Packet<'_>) -> Result<bool, GvspError> {
        if p.block_id != self.block_id {
            return Ok(false);
        }
        match &p.content {
            Content::Leader(l) => {
                if self.leader.is_none() {
                    let size = self.negotiated.check(l)?;
                    self.data = vec![0; size];
                    self.received = vec![false; size.div_ceil(self.chunk)];
                    self.leader = Some(*l);
                }
            }
            Content::Payload(d) => {
                if self.leader.is_none() {
                    // Payload before leader: keep nothing; it will be asked again.
                    return Ok(false);
                }
                let Some((start, want)) = self.place(p.packet_id) else {
                    self.malformed = self.malformed.saturating_add(1);
                    return Ok(false);
                };
                if d.len() != want {
                    self.malformed = self.malformed.saturating_add(1);
                    return Ok(false);
                }
                self.data[start..start + want].copy_from_slice(d);
                self.received[start / self.chunk] = true;
            }
            Content::Trailer { .. } => self.trailer_seen = true,
        }
        Ok(true)
    }

    /// Where payload packet `packet_id` goes: (offset, length), or `None` if the block
    /// has no such packet.
    fn place(&self, packet_id: u32) -> Option<(usize, usize)> {
        let k = usize::try_from(packet_id).ok()?;
        if k == 0 || k > self.received.len() {
            return None;
        }
        let start = (k - 1).checked_mul(self.chunk)?;
        let left = self.data.len().checked_sub(start)?;
        let want = if k == self.received.len() {
            left
        } else {
            self.chunk.min(left)
        };
        Some((start, want))
    }

    pub fn trailer_seen(&self) -> bool {
        self.trailer_seen
    }

    /// Payload packet ids still missing (all of them if the leader is missing).
    pub fn missing(&self) -> Vec<u32> {
        self.received
            .iter()
            .enumerate()
            .filter(|(_, r)| !**r)
            .map(|(i, _)| i as u32 + 1)
            .collect()
    }

    pub fn is_complete(&self) -> bool {
        self.leader.is_some() && self.received.iter().all(|r| *r)
    }

    /// The payload once complete.
    pub fn into_data(self) -> Option<(ImageLeader, Vec<u8>)> {
        if self.is_complete() {
            Some((self.leader?, self.data))
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leader(w: u32, h: u32, pf: u32) -> ImageLeader {
        ImageLeader {
            timestamp: 0x1_0000_0002,
            pixel_format: pf,
            width: w,
            height: h,
            offset_x: 0,
            offset_y: 0,
        }
    }

    #[test]
    fn leader_bytes_and_round_trip() {
        let l = leader(640, 480, pfnc::MONO8);
        let mut b = Vec::new();
        assert!(encode_frame_packet(5, &l, &[0; 640 * 480], 1500, 0, &mut b));
        assert_eq!(&b[..8], &[0, 0, 0, 5, 1, 0, 0, 0]);
        assert_eq!(b.len(), 8 + 36);
        assert_eq!(Packet::decode(&b).unwrap().content, Content::Leader(l));
    }

    #[test]
    fn frames_reassemble_in_any_order_and_report_missing_packets() {
        let l = leader(37, 11, pfnc::MONO16);
        let data: Vec<u8> = (0..l.payload_size()).map(|i| (i * 7) as u8).collect();
        let scps = 36 + 100;
        let n = payload_packets(data.len(), scps);
        assert_eq!(n, 9);
        let mut pkts = Vec::new();
        for id in 0..=n + 1 {
            let mut b = Vec::new();
            assert!(encode_frame_packet(3, &l, &data, scps, id, &mut b));
            pkts.push(b);
        }
        let mut b = Vec::new();
        assert!(!encode_frame_packet(3, &l, &data, scps, n + 2, &mut b));
        let mut a = Assembler::new(3, scps, Negotiated::new(37, 11, pfnc::MONO16).unwrap());
        // Leader, then payload backwards except packet 4, then trailer.
        assert_eq!(a.push(&Packet::decode(&pkts[0]).unwrap()), Ok(true));
        for id in (1..=n).rev().filter(|&i| i != 4) {
            assert_eq!(
                a.push(&Packet::decode(&pkts[id as usize]).unwrap()),
                Ok(true)
            );
        }
        assert_eq!(
            a.push(&Packet::decode(&pkts[n as usize + 1]).unwrap()),
            Ok(true)
        );
        assert!(a.trailer_seen());
        assert_eq!(a.missing(), vec![4]);
        assert!(!a.is_complete());
        assert_eq!(a.push(&Packet::decode(&pkts[4]).unwrap()), Ok(true));
        let (got_l, got) = a.into_data().unwrap();
        assert_eq!(got_l, l);
        assert_eq!(got, data);
    }

    #[test]
    fn wrong_sizes_are_counted_not_stored() {
        let l = leader(10, 10, pfnc::MONO8);
        let mut a = Assembler::new(1, 36 + 40, Negotiated::new(10, 10, pfnc::MONO8).unwrap());
        assert_eq!(
            a.push(&Packet {
                status: 0,
                block_id: 1,
                packet_id: 0,
                content: Content::Leader(l),
            }),
            Ok(true)
        );
        let short = [0u8; 39];
        assert_eq!(
            a.push(&Packet {
                status: 0,
                block_id: 1,
                packet_id: 1,
                content: Content::Payload(&short),
            }),
            Ok(false)
        );
        assert_eq!(a.malformed, 1);
        assert_eq!(a.missing(), vec![1, 2, 3]);
        assert_eq!(
            Packet::decode(&[0, 0, 0, 1, 0x81, 0, 0, 0]),
            Err(GvspError::ExtendedId)
        );
    }

    fn packet(block_id: u16, packet_id: u32, content: Content<'_>) -> Packet<'_> {
        Packet {
            status: 0,
            block_id,
            packet_id,
            content,
        }
    }

    #[test]
    fn crafted_leaders_are_refused_before_any_allocation() {
        let sxga = Negotiated::new(1280, 1024, pfnc::MONO8).unwrap();
        assert_eq!(sxga.payload_size, 1_310_720);
        let mut a = Assembler::new(1, 1500, sxga);
        let e = a
            .push(&packet(
                1,
                0,
                Content::Leader(leader(65535, 65535, pfnc::MONO8)),
            ))
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "GVSP leader: width 65535 x height 65535 at 8 bit is 4294836225 bytes, more than the 1310720-byte payload negotiated at open"
        );
        // The largest numbers a leader can hold: no overflow, same refusal.
        let e = a
            .push(&packet(
                1,
                0,
                Content::Leader(leader(u32::MAX, u32::MAX, 0x01FF_0001)),
            ))
            .unwrap_err();
        assert!(
            matches!(e, GvspError::LeaderTooLarge { bits: 255, .. }),
            "{e}"
        );
        // Smaller, but not what was negotiated: refused too, naming both.
        let e = a
            .push(&packet(
                1,
                0,
                Content::Leader(leader(640, 480, pfnc::MONO16)),
            ))
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "GVSP leader: 640x480 Mono16, but 1280x1024 Mono8 was negotiated at open"
        );
        assert!(a.leader.is_none() && a.missing().is_empty() && !a.is_complete());
        // Payload before a leader, and after a refused one, is not stored.
        assert_eq!(
            a.push(&packet(1, 1, Content::Payload(&[0; 1464]))),
            Ok(false)
        );
        // The real leader is still taken after the refused ones.
        assert_eq!(
            a.push(&packet(
                1,
                0,
                Content::Leader(leader(1280, 1024, pfnc::MONO8))
            )),
            Ok(true)
        );
        assert_eq!(a.missing().len(), 896);
    }

    #[test]
    fn crafted_payload_positions_are_counted_not_stored() {
        let mut a = Assembler::new(2, 36 + 40, Negotiated::new(10, 10, pfnc::MONO8).unwrap());
        a.push(&packet(2, 0, Content::Leader(leader(10, 10, pfnc::MONO8))))
            .unwrap();
        for id in [0, 4, 0x00FF_FFFF, u32::MAX] {
            assert_eq!(
                a.push(&packet(2, id, Content::Payload(&[0; 40]))),
                Ok(false)
            );
        }
        // The last packet holds the remainder (20 bytes), not a whole chunk.
        assert_eq!(a.push(&packet(2, 3, Content::Payload(&[0; 40]))), Ok(false));
        assert_eq!(a.push(&packet(2, 3, Content::Payload(&[0; 20]))), Ok(true));
        assert_eq!(a.malformed, 5);
        assert_eq!(a.missing(), vec![1, 2]);
        // Another block's packets are ignored.
        assert_eq!(a.push(&packet(3, 1, Content::Payload(&[0; 40]))), Ok(false));
    }

    #[test]
    fn negotiated_formats_are_bounded() {
        assert!(Negotiated::new(0, 480, pfnc::MONO8).is_err());
        assert!(Negotiated::new(640, 480, 0).is_err());
        let e = Negotiated::new(u32::MAX, u32::MAX, pfnc::MONO16).unwrap_err();
        assert!(e.to_string().contains("MAX_PAYLOAD_SIZE"), "{e}");
        assert!(Negotiated::new(16384, 16384, pfnc::MONO16).is_ok());
        let huge = leader(u32::MAX, u32::MAX, 0x01FF_0001);
        assert_eq!(huge.payload_size(), usize::MAX);
    }
}
