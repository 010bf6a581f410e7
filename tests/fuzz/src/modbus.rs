//! Modbus frames: PDUs both ways, RTU framing and CRC, the TCP MBAP header.

use protocol::modbus::frame::{
    rtu_crc_ok, rtu_frame, rtu_request_len, rtu_response_len, FrameLen, Mbap,
};
use protocol::modbus::{Request, Response};

/// Every record parsed as a request and a response PDU (what parses re-encodes to a
/// PDU that parses to the same value), as RTU frames (the length a frame claims is
/// within what is buffered or asks for more, never less than a header), and as a TCP
/// ADU.
pub fn modbus_frame(data: &[u8]) {
    for r in crate::records(data) {
        if let Ok(req) = Request::parse(r) {
            let pdu = req.encode();
            assert_eq!(Request::parse(&pdu).ok(), Some(req.clone()), "{pdu:?}");
            assert_eq!(req.function(), pdu[0]);
        }
        if let Some(resp) = Response::parse(r) {
            let pdu = resp.encode();
            assert_eq!(Response::parse(&pdu), Some(resp), "{pdu:?}");
        }
        for len in [rtu_request_len(r), rtu_response_len(r)] {
            if let FrameLen::Bytes(n) = len {
                assert!((4..=268).contains(&n), "RTU length {n}");
            }
        }
        if rtu_crc_ok(r) {
            // The CRC covers everything but itself: writing the frame again gives it.
            let (unit, pdu) = (r[0], &r[1..r.len() - 2]);
            assert_eq!(rtu_frame(unit, pdu), r);
        }
        if let Some(h) = Mbap::parse(r) {
            let pdu = &r[Mbap::LEN..];
            if h.protocol == 0 && usize::from(h.length) == pdu.len() + 1 {
                assert_eq!(Mbap::frame(h.transaction, h.unit, pdu), r);
            }
        }
    }
}
