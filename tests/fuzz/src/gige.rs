//! GigE Vision: GVCP control packets, GVSP stream packets and frames reassembled from
//! them, the GenICam XML of a camera, ZIP archives of it, and its `Local:` URL.

use drivers::gige::genicam::{GenICam, Location};
use protocol::gige::gvcp::{Ack, CommandPacket};
use protocol::gige::gvsp::{Assembler, Negotiated, Packet};
use protocol::gige::{parse_local_url, pfnc, zip};

/// One datagram decoded as a GVCP acknowledge and as a command: an ack that decodes
/// re-encodes to one that decodes the same; a command that decodes re-encodes to one
/// that decodes the same and can be described.
pub fn gvcp(data: &[u8]) {
    if let Ok(ack) = Ack::decode(data) {
        let bytes = ack.encode();
        assert_eq!(Ack::decode(&bytes).as_ref(), Ok(&ack), "{bytes:?}");
        let _ = ack.ack_code();
    }
    if let Ok(c) = CommandPacket::decode(data) {
        let _ = c.command.describe();
        let bytes = c.encode();
        assert_eq!(CommandPacket::decode(&bytes).as_ref(), Ok(&c), "{bytes:?}");
    }
}

/// A stream: four header bytes choose the negotiated format (width, height, pixel
/// format) and the packet size; every record after them is one datagram, decoded and
/// pushed into one assembler. The missing packets are always inside the block, a
/// complete block has none, and the frame it gives has the negotiated size.
pub fn gvsp(data: &[u8]) {
    let [w, h, f, s, rest @ ..] = data else {
        return;
    };
    let format = [pfnc::MONO8, pfnc::MONO16, 0x010C_0001][usize::from(*f) % 3];
    let Ok(negotiated) = Negotiated::new(u32::from(w % 64) + 1, u32::from(h % 64) + 1, format)
    else {
        return;
    };
    let packet_size = [37, 44, 100, 200, 291, 1500, 0, u32::MAX][usize::from(*s) % 8];
    let mut a = Assembler::new(1, packet_size, negotiated);
    for r in crate::records(rest) {
        let Ok(p) = Packet::decode(r) else {
            continue;
        };
        let _ = a.push(&p);
        let missing = a.missing();
        assert!(missing.windows(2).all(|m| m[0] < m[1]));
        assert!(missing.first().is_none_or(|&m| m >= 1));
        if a.is_complete() {
            assert!(missing.is_empty());
        }
    }
    if let Some((leader, frame)) = a.clone().into_data() {
        assert!(frame.len() <= negotiated.payload_size);
        assert_eq!(frame.len(), leader.payload_size());
    }
}

/// Features the driver asks a camera's XML for.
const FEATURES: &[&str] = &[
    "Width",
    "Height",
    "PixelFormat",
    "TriggerMode",
    "TriggerSelector",
    "TriggerSource",
    "TriggerSoftware",
    "AcquisitionMode",
    "AcquisitionStart",
    "AcquisitionStop",
    "ExposureTime",
    "GevSCPSPacketSize",
];

/// A camera's GenICam XML: every feature the driver uses located, enumerations and
/// commands read. A register comes back 1 to 8 bytes long inside the 32-bit address
/// space, with its bit field inside it.
pub fn genicam_xml(data: &[u8]) {
    let xml = GenICam::new(String::from_utf8_lossy(data).into_owned());
    for f in FEATURES {
        let _ = xml.has(f);
        if let Ok(Location::Register {
            address,
            length,
            field,
            ..
        }) = xml.locate(f)
        {
            assert!((1..=8).contains(&length), "{f}: {length} bytes");
            assert!(u64::from(address) + u64::from(length) <= 1 << 32, "{f}");
            if let Some((shift, width)) = field {
                assert!(width >= 1 && u64::from(shift) + u64::from(width) <= 8 * u64::from(length));
            }
        }
        let _ = xml.command_value(f);
        let _ = xml.enum_name(f, 0x0108_0001);
        let _ = xml.enum_name(f, 1);
    }
    for (f, e) in [
        ("PixelFormat", "Mono8"),
        ("PixelFormat", "Mono16"),
        ("TriggerMode", "On"),
    ] {
        let _ = xml.enum_value(f, e);
    }
}

/// A ZIP archive of a GenICam XML: the first file comes out at most
/// `MAX_UNCOMPRESSED` bytes; stored again, it reads back the same.
pub fn gige_zip(data: &[u8]) {
    if let Ok((name, contents)) = zip::first_file(data) {
        assert!(contents.len() <= zip::MAX_UNCOMPRESSED);
        for deflate in [false, true] {
            let again = zip::store_one(&name, &contents, deflate);
            assert_eq!(
                zip::first_file(&again),
                Ok((name.clone(), contents.clone()))
            );
        }
    }
}

/// The XML URL registers (`Local:<file>;<addr>;<size>`).
pub fn gige_url(data: &[u8]) {
    if let Ok((name, address, size)) = parse_local_url(data) {
        let written = format!("Local:{name};{address:x};{size:x}");
        assert_eq!(
            parse_local_url(written.as_bytes()),
            Ok((name, address, size)),
            "written as {written:?}"
        );
    }
}
