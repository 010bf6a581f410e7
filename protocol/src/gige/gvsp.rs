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
    /// Bytes of image data the block carries.
    pub fn payload_size(&self) -> usize {
        self.width as usize
            * self.height as usize
            * pfnc::bits_per_pixel(self.pixel_format) as usize
            / 8
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

/// Number of payload packets of a frame.
pub fn payload_packets(payload_size: usize, packet_size: u32) -> u32 {
    payload_size.div_ceil(chunk_size(packet_size)) as u32
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

/// Reassembles one block from its packets, in any order.
#[derive(Debug, Clone)]
pub struct Assembler {
    pub block_id: u16,
    pub leader: Option<ImageLeader>,
    chunk: usize,
    data: Vec<u8>,
    received: Vec<bool>,
    trailer_seen: bool,
    /// Packets whose size or position did not fit the leader (a corrupt stream).
    pub malformed: u32,
}

impl Assembler {
    /// `packet_size` is the SCPS the device was told to use.
    pub fn new(block_id: u16, packet_size: u32) -> Self {
        Self {
            block_id,
            leader: None,
            chunk: chunk_size(packet_size),
            data: Vec::new(),
            received: Vec::new(),
            trailer_seen: false,
            malformed: 0,
        }
    }

    /// Takes one packet of this block (others are ignored; returns whether it was used).
    pub fn push(&mut self, p: &Packet<'_>) -> bool {
        if p.block_id != self.block_id {
            return false;
        }
        match &p.content {
            Content::Leader(l) => {
                if self.leader.is_none() {
                    let size = l.payload_size();
                    self.data = vec![0; size];
                    self.received = vec![false; size.div_ceil(self.chunk)];
                    self.leader = Some(*l);
                }
            }
            Content::Payload(d) => {
                let Some(l) = self.leader else {
                    // Payload before leader: keep nothing; it will be asked again.
                    return false;
                };
                let k = p.packet_id as usize;
                let n = self.received.len();
                let start = k.wrapping_sub(1).wrapping_mul(self.chunk);
                let want = if k == n {
                    l.payload_size() - start
                } else {
                    self.chunk
                };
                if k == 0 || k > n || d.len() != want {
                    self.malformed += 1;
                    return false;
                }
                self.data[start..start + want].copy_from_slice(d);
                self.received[k - 1] = true;
            }
            Content::Trailer { .. } => self.trailer_seen = true,
        }
        true
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
        let mut a = Assembler::new(3, scps);
        // Leader, then payload backwards except packet 4, then trailer.
        a.push(&Packet::decode(&pkts[0]).unwrap());
        for id in (1..=n).rev().filter(|&i| i != 4) {
            a.push(&Packet::decode(&pkts[id as usize]).unwrap());
        }
        a.push(&Packet::decode(&pkts[n as usize + 1]).unwrap());
        assert!(a.trailer_seen());
        assert_eq!(a.missing(), vec![4]);
        assert!(!a.is_complete());
        a.push(&Packet::decode(&pkts[4]).unwrap());
        let (got_l, got) = a.into_data().unwrap();
        assert_eq!(got_l, l);
        assert_eq!(got, data);
    }

    #[test]
    fn wrong_sizes_are_counted_not_stored() {
        let l = leader(10, 10, pfnc::MONO8);
        let mut a = Assembler::new(1, 36 + 40);
        a.push(&Packet {
            status: 0,
            block_id: 1,
            packet_id: 0,
            content: Content::Leader(l),
        });
        let short = [0u8; 39];
        a.push(&Packet {
            status: 0,
            block_id: 1,
            packet_id: 1,
            content: Content::Payload(&short),
        });
        assert_eq!(a.malformed, 1);
        assert_eq!(a.missing(), vec![1, 2, 3]);
        assert_eq!(
            Packet::decode(&[0, 0, 0, 1, 0x81, 0, 0, 0]),
            Err(GvspError::ExtendedId)
        );
    }
}
