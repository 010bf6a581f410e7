//! CANopen: the SDO client and server fed arbitrary frames, and EDS files.

use protocol::canopen::od::ObjectDictionary;
use protocol::canopen::sdo::{AbortCode, ClientStep, ObjectAccess, SdoClient, SdoServer};
use protocol::canopen::NodeId;
use std::collections::BTreeMap;

/// An SDO client on one node: the first byte picks what it starts (upload, expedited
/// or segmented download of a length from the second byte); every record after that
/// is a response frame (up to 8 bytes; longer ones are cut as a CAN frame would be),
/// 10 ms apart, with the timeout polled between them. A finished or failed transfer
/// starts the next one. An upload never returns more bytes than the responses
/// carried (7 a frame; a short frame is padded with zeros), a segmented one only
/// after the client asked for a segment; every frame the client asks to send is an
/// 8-byte SDO request to the node.
pub fn sdo_client(data: &[u8]) {
    let [op, len, rest @ ..] = data else {
        return;
    };
    let node = NodeId::new(5).expect("node 5");
    let mut client = SdoClient::new(node, 0.05);
    let payload: Vec<u8> = (0..*len).collect();
    let start = |c: &mut SdoClient, k: usize, now: f64| match (usize::from(*op) + k) % 3 {
        0 => c.upload(0x6064, 0, now),
        1 => c.download(0x607A, 0, &payload[..payload.len().min(4)], now),
        _ => c.download(0x1018, 1, &payload, now),
    };
    let check = |frame: &protocol::can::CanFrame| {
        assert_eq!(frame.id().as_standard(), Some(node.sdo_rx()));
        assert_eq!(frame.data().len(), 8);
    };
    check(&start(&mut client, 0, 0.0));
    let mut fed = 0usize;
    let mut asked_segment = false;
    let mut transfers = 1;
    for (k, r) in crate::records(rest).enumerate() {
        let now = 0.01 * (k + 1) as f64;
        let frame = &r[..r.len().min(8)];
        fed += 7;
        let step = match client.poll(now) {
            Some(step) => step,
            None => client.on_response(frame, now),
        };
        match step {
            ClientStep::Send(f) => {
                check(&f);
                // Upload segment request (ccs 3).
                asked_segment |= f.data()[0] >> 5 == 3;
            }
            ClientStep::Uploaded(bytes) => {
                assert!(bytes.len() <= fed, "{} bytes from {fed}", bytes.len());
                let segment = frame.first().is_none_or(|b| b >> 5 == 0);
                assert!(!segment || asked_segment, "a segment nobody asked for");
            }
            ClientStep::Failed { error, send } => {
                let _ = (error.code(), error.to_string());
                if let Some(f) = send {
                    check(&f);
                }
            }
            ClientStep::Downloaded | ClientStep::Ignored => {}
        }
        if !client.busy() {
            fed = 0;
            asked_segment = false;
            check(&start(&mut client, transfers, now));
            transfers += 1;
        }
    }
    if client.busy() {
        if let Some(f) = client.cancel(AbortCode::TIMEOUT) {
            check(&f);
        }
    }
    assert!(!client.busy());
}

/// A small dictionary: a few entries of fixed size, one that takes any length up to
/// 64 bytes, one read-only.
struct Od(BTreeMap<(u16, u8), Vec<u8>>);

impl ObjectAccess for Od {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        self.0
            .get(&(index, sub))
            .cloned()
            .ok_or(AbortCode::NO_OBJECT)
    }
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        if (index, sub) == (0x1018, 1) {
            return Err(AbortCode::READ_ONLY);
        }
        let slot = self.0.get_mut(&(index, sub)).ok_or(AbortCode::NO_OBJECT)?;
        if index == 0x1008 {
            if data.len() > 64 {
                return Err(AbortCode::TOO_LONG);
            }
        } else if data.len() != slot.len() {
            return Err(AbortCode::LENGTH_MISMATCH);
        }
        *slot = data.to_vec();
        Ok(())
    }
}

/// An SDO server fed every record as a request frame (cut to 8 bytes): it answers
/// with an 8-byte frame or nothing, and never stores more than a frame's worth of
/// data per request on top of what it held.
pub fn sdo_server(data: &[u8]) {
    let mut od = Od(BTreeMap::from([
        ((0x6040, 0), vec![0, 0]),
        ((0x607A, 0), vec![0; 4]),
        ((0x1008, 0), b"fuzz drive name".to_vec()),
        ((0x1018, 1), vec![1, 0, 0, 0]),
        ((0x6064, 0), vec![0x10, 0x20, 0x30, 0x40]),
    ]));
    let mut server = SdoServer::new();
    let mut aborts = 0;
    for r in crate::records(data) {
        let frame = &r[..r.len().min(8)];
        let _answer: Option<[u8; 8]> = server.on_request(frame, &mut od);
        assert!(server.aborts_sent >= aborts);
        aborts = server.aborts_sent;
        assert!(od.0.values().all(|v| v.len() <= 64));
    }
}

/// EDS text for a node whose id is the first byte: parsed, then every entry checked
/// the way the emulated node and the CiA 402 driver check them.
pub fn canopen_eds(data: &[u8]) {
    let Some((&id, text)) = data.split_first() else {
        return;
    };
    let Some(node) = NodeId::new(id % 127 + 1) else {
        return;
    };
    let Ok(text) = std::str::from_utf8(text) else {
        return;
    };
    match ObjectDictionary::from_eds("fuzz.eds", text, node) {
        Ok(od) => {
            for v in od.variables() {
                let _ = v.check_read();
                let _ = v.check_write(&v.default);
                let _ = v.bits();
                if v.data_type.size().is_some() {
                    let _ = protocol::canopen::od::decode_int(v.data_type, &v.default);
                }
                assert!(od.variable(v.index, v.sub).is_ok());
            }
            let _ = link_spec::canopen::check_drive_eds(&od);
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}
