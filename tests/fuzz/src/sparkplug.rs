//! What the northbound reads from the network: NCMD payloads and topics.

use sparkplug::{Payload, Topic};

/// Any bytes as a Sparkplug B payload (an NCMD from the broker) and, as text, a topic:
/// decoding never panics; a decoded payload encodes and decodes to itself; a parsed
/// topic prints back to the same text.
pub fn sparkplug_ncmd(data: &[u8]) {
    if let Ok(p) = Payload::decode_bytes(data) {
        let _ = sparkplug::asks_rebirth(&p);
        let again = Payload::decode_bytes(&p.encode_to_bytes()).expect("our own encoding");
        // NaN floats compare unequal to themselves: compare the encodings instead.
        assert_eq!(again.encode_to_bytes(), p.encode_to_bytes());
    }
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(t) = Topic::parse(text) {
            assert_eq!(t.to_string(), text);
        }
    }
}
