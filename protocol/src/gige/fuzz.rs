//! Deterministic randomized input for everything GigE Vision reads from the network:
//! URL registers, GVCP acknowledges and commands, GVSP packets and sequences of them
//! through an [`Assembler`], and ZIP archives. Valid encodings are mutated (bytes
//! flipped, fields overwritten with extremes, cut short) as well as generated at
//! random. Nothing may panic; the first offending input is reported.

use super::gvcp::{Ack, AckBody, Command, CommandPacket};
use super::gvsp::{encode_frame_packet, Assembler, ImageLeader, Negotiated, Packet};
use super::{parse_local_url, pfnc, zip};
use std::fmt::Debug;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::Instant;

/// xorshift64*: small, fast, the same sequence on every machine.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(seed | 1)
    }
    fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn pick<T: Copy>(&mut self, from: &[T]) -> T {
        from[self.below(from.len())]
    }
    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next() as u8).collect()
    }
    /// 0..max random bytes.
    fn some_bytes(&mut self, max: usize) -> Vec<u8> {
        let n = self.below(max);
        self.bytes(n)
    }
    /// A 32-bit value that is often an edge.
    fn edge32(&mut self) -> u32 {
        match self.below(6) {
            0 => 0,
            1 => u32::MAX,
            2 => 1 << self.below(32),
            3 => self.below(5000) as u32,
            _ => self.next() as u32,
        }
    }
}

/// Mutates `b` in place: flipped bytes, a 16- or 32-bit field set to an edge value,
/// cut short or extended.
fn mutate(rng: &mut Rng, b: &mut Vec<u8>) {
    for _ in 0..1 + rng.below(4) {
        if b.is_empty() {
            b.extend(rng.some_bytes(16));
            continue;
        }
        let at = rng.below(b.len());
        match rng.below(5) {
            0 => b[at] ^= 1 << rng.below(8),
            1 => b[at] = rng.next() as u8,
            2 => {
                let v = rng.edge32().to_be_bytes();
                let le = rng.below(2) == 0;
                for (k, x) in v.iter().enumerate() {
                    if let Some(slot) = b.get_mut(at + k) {
                        *slot = if le { v[3 - k] } else { *x };
                    }
                }
            }
            3 => b.truncate(at),
            _ => b.extend(rng.some_bytes(64)),
        }
    }
}

/// Runs `f` on `input`; a panic fails the test naming the input.
fn no_panic<I: Debug, R>(what: &str, n: usize, input: &I, f: impl FnOnce(&I) -> R) -> R {
    match catch_unwind(AssertUnwindSafe(|| f(input))) {
        Ok(r) => r,
        Err(_) => panic!("{what}: input {n} panicked: {input:?}"),
    }
}

#[test]
fn random_url_registers_never_panic() {
    let mut rng = Rng::new(0x0075_726C);
    let pieces: &[&[u8]] = &[
        b"Local:",
        b"local:",
        b"LOCAL:",
        b"Loca",
        b"File:",
        b"http://",
        b"cam.xml",
        b"cam.zip",
        b";",
        b";;",
        b"0x",
        b"0X",
        b"?SchemaVersion=1.1.0",
        b"FFFFFFFF",
        b"100000000",
        b"10000",
        b"3a1f",
        b"-1",
        b"+1",
        b" ",
        b"\0",
        "é".as_bytes(),
        "\u{1F600}".as_bytes(),
        &[0xC3],
        &[0xFF, 0xFE],
        &[0xE2, 0x82],
    ];
    let count = 20_000;
    let start = Instant::now();
    let mut parsed = 0;
    for n in 0..count {
        let mut raw = Vec::new();
        if rng.below(2) == 0 {
            // The format's skeleton with random pieces in its places.
            let scheme: &[&[u8]] = &[b"Local:", b"local:", b"LOCAL:"];
            raw.extend_from_slice(rng.pick(scheme));
            let names: &[&[u8]] = &[b"cam.xml", b"cam.zip", "é.xml".as_bytes(), b" ", b""];
            let hex: &[&[u8]] = &[
                b"0x",
                b"10000",
                b"3a1f",
                b"FFFFFFFF",
                b"100000000",
                b"-1",
                b"+1",
                b" ",
                b"?SchemaVersion=1.1.0",
                &[0xC3],
            ];
            for (field, sep) in [(names, &b";"[..]), (hex, b";"), (hex, b"")] {
                for _ in 0..1 + rng.below(2) {
                    let from = if rng.below(8) == 0 { pieces } else { field };
                    raw.extend_from_slice(rng.pick(from));
                }
                raw.extend_from_slice(sep);
            }
        } else {
            for _ in 0..rng.below(12) {
                raw.extend_from_slice(rng.pick(pieces));
            }
        }
        if rng.below(4) == 0 {
            mutate(&mut rng, &mut raw);
        }
        raw.truncate(super::bootstrap::URL_LEN);
        if no_panic("URL register", n, &raw, |r| parse_local_url(r)).is_ok() {
            parsed += 1;
        }
    }
    eprintln!(
        "{count} URL registers in {:?} ({parsed} parsed)",
        start.elapsed()
    );
    assert!(
        parsed > 100,
        "only {parsed} parsed: the generator misses the format"
    );
}

fn sample_acks(rng: &mut Rng) -> Vec<u8> {
    let body = match rng.below(7) {
        0 => AckBody::Discovery(rng.bytes(super::bootstrap::DISCOVERY_LEN)),
        1 => AckBody::ReadReg((0..1 + rng.below(8)).map(|_| rng.edge32()).collect()),
        2 => AckBody::WriteReg {
            index: rng.next() as u16,
        },
        3 => AckBody::ReadMem {
            address: rng.edge32(),
            data: rng.some_bytes(537),
        },
        4 => AckBody::WriteMem {
            index: rng.next() as u16,
        },
        5 => AckBody::Pending {
            ms: rng.next() as u16,
        },
        _ => AckBody::Other {
            code: rng.next() as u16,
            payload: rng.some_bytes(64),
        },
    };
    Ack {
        status: match rng.below(5) {
            0 => rng.next() as u16,
            k => [0, 0, 0x8001, 0x8006][k - 1],
        },
        ack_id: rng.next() as u16,
        body,
    }
    .encode()
}

fn sample_command(rng: &mut Rng) -> Vec<u8> {
    let command = match rng.below(6) {
        0 => Command::Discovery,
        1 => Command::ReadReg((0..1 + rng.below(8)).map(|_| rng.edge32()).collect()),
        2 => Command::WriteReg(
            (0..1 + rng.below(8))
                .map(|_| (rng.edge32(), rng.edge32()))
                .collect(),
        ),
        3 => Command::ReadMem {
            address: rng.edge32(),
            count: rng.next() as u16,
        },
        4 => Command::WriteMem {
            address: rng.edge32(),
            data: rng.some_bytes(600),
        },
        _ => Command::PacketResend {
            channel: rng.next() as u16,
            block_id: rng.next() as u16,
            first: rng.edge32(),
            last: rng.edge32(),
        },
    };
    CommandPacket {
        flags: rng.next() as u8,
        req_id: rng.next() as u16,
        command,
    }
    .encode()
}

#[test]
fn random_gvcp_packets_never_panic() {
    let mut rng = Rng::new(0x6776_6370);
    let count = 30_000;
    let start = Instant::now();
    let (mut acks, mut commands) = (0, 0);
    for n in 0..count {
        let mut b = match rng.below(3) {
            0 => sample_acks(&mut rng),
            1 => sample_command(&mut rng),
            _ => rng.some_bytes(700),
        };
        if rng.below(4) > 0 {
            mutate(&mut rng, &mut b);
        }
        if let Ok(a) = no_panic("GVCP ack", n, &b, |b| Ack::decode(b)) {
            acks += 1;
            // What decodes re-encodes and decodes to the same ack.
            let again = no_panic("GVCP ack re-encoded", n, &b, |_| Ack::decode(&a.encode()));
            assert_eq!(again.as_ref(), Ok(&a), "input {n}: {b:?}");
        }
        if let Ok(c) = no_panic("GVCP command", n, &b, |b| CommandPacket::decode(b)) {
            commands += 1;
            no_panic("GVCP command described", n, &c, |c| c.command.describe());
        }
    }
    eprintln!(
        "{count} GVCP datagrams in {:?} ({acks} decoded as acks, {commands} as commands)",
        start.elapsed()
    );
    assert!(
        acks > 1000 && commands > 1000,
        "{acks} acks, {commands} commands"
    );
}

#[test]
fn random_gvsp_packets_and_sequences_never_panic() {
    let mut rng = Rng::new(0x6776_7370);
    let formats = [
        pfnc::MONO8,
        pfnc::MONO16,
        0x010C_0001,
        0x0101_0001,
        0x01FF_0001,
        0,
    ];
    let count = 40_000;
    let start = Instant::now();
    let (mut decoded, mut used, mut frames) = (0, 0, 0);
    let mut n = 0;
    while n < count {
        // One block: a negotiated format, a camera sending it (or not), a packet size.
        let (w, h) = (1 + rng.below(40) as u32, 1 + rng.below(40) as u32);
        let pf = rng.pick(&formats[..3]);
        let Ok(negotiated) = Negotiated::new(w, h, pf) else {
            continue;
        };
        let packet_size = rng.pick(&[0, 1, 36, 37, 40, 64, 100, 1500, u32::MAX]);
        let leader = ImageLeader {
            timestamp: rng.next(),
            pixel_format: if rng.below(4) == 0 {
                rng.pick(&formats)
            } else {
                pf
            },
            width: if rng.below(4) == 0 { rng.edge32() } else { w },
            height: if rng.below(4) == 0 { rng.edge32() } else { h },
            offset_x: rng.edge32(),
            offset_y: rng.edge32(),
        };
        let data = rng.bytes(leader.payload_size().min(4000));
        let block_id = rng.next() as u16;
        let mut a = Assembler::new(block_id, packet_size, negotiated);
        for _ in 0..rng.below(80) {
            n += 1;
            let mut b = Vec::new();
            let id = match rng.below(4) {
                0 => rng.edge32(),
                _ => rng.below(1 + data.len() / 4 + 2) as u32,
            };
            let input = (block_id, leader, data.len(), packet_size, id);
            no_panic("GVSP encode", n, &input, |_| {
                encode_frame_packet(block_id, &leader, &data, packet_size, id, &mut b)
            });
            if b.is_empty() || rng.below(3) == 0 {
                b.extend(rng.some_bytes(100));
            }
            if rng.below(3) == 0 {
                mutate(&mut rng, &mut b);
            }
            let Ok(p) = no_panic("GVSP decode", n, &b, |_| Packet::decode(&b)) else {
                continue;
            };
            decoded += 1;
            if no_panic("Assembler::push", n, &(&b, *a.negotiated()), |_| a.push(&p)) == Ok(true) {
                used += 1;
            }
            no_panic("Assembler::missing", n, &b, |_| {
                (a.missing(), a.is_complete())
            });
        }
        if no_panic("Assembler::into_data", n, &a.clone(), |a| {
            a.clone().into_data()
        })
        .is_some()
        {
            frames += 1;
        }
    }
    eprintln!(
        "{n} GVSP datagrams in {:?} ({decoded} decoded, {used} taken by an assembler, {frames} frames complete)",
        start.elapsed()
    );
    assert!(used > 1000 && frames > 10, "{used} used, {frames} frames");
}

#[test]
fn random_zip_archives_never_panic() {
    let mut rng = Rng::new(0x007A_6970);
    // A slice of a real GenICam XML: real text, small enough to inflate and CRC fast.
    let xml = &include_bytes!("../../../config/gige/sim-camera.xml")[..2048];
    let samples = [
        zip::store_one("cam.xml", xml, true),
        zip::store_one("cam.xml", xml, false),
        zip::store_one("a.xml", b"<a/>", true),
        zip::store_one("", b"", false),
    ];
    let count = 3_000;
    let start = Instant::now();
    let mut read = 0;
    for n in 0..count {
        let mut z = match rng.below(8) {
            0 => rng.some_bytes(200),
            k => samples[k % samples.len()].clone(),
        };
        // Often a field of the small archives' headers, sometimes anywhere.
        for _ in 0..1 + rng.below(3) {
            mutate(&mut rng, &mut z);
        }
        if no_panic("zip::first_file", n, &z, |z| zip::first_file(z)).is_ok() {
            read += 1;
        }
    }
    eprintln!(
        "{count} ZIP archives in {:?} ({read} read)",
        start.elapsed()
    );
}
