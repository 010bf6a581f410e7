//! SLCAN (Lawicel) both ways: adapter messages and host commands.

use protocol::slcan::{Command, CommandDecoder, Message, MessageDecoder};

/// Each CR/BEL-separated line parsed as a message and as a command; what parses is
/// encoded and parses back to the same value. Both stream decoders fed whole and in
/// chunks agree and never deliver more values than lines.
pub fn slcan(data: &[u8]) {
    let Some((&seed, data)) = data.split_first() else {
        return;
    };
    for line in data.split(|&b| b == b'\r' || b == 0x07) {
        if let Ok(m) = Message::parse(line) {
            let bytes = m.encode();
            let (last, body) = bytes.split_last().expect("a terminator");
            assert!(*last == b'\r' || *last == 0x07);
            let again = if *last == 0x07 {
                Message::Error
            } else {
                Message::parse(body).unwrap_or_else(|e| panic!("{m:?} -> {bytes:?}: {e}"))
            };
            assert_eq!(again, m, "message written as {bytes:?}");
        }
        if let Ok(c) = Command::parse(line) {
            let bytes = c.encode();
            let again = Command::parse(&bytes[..bytes.len() - 1])
                .unwrap_or_else(|e| panic!("{c:?} -> {bytes:?}: {e}"));
            assert_eq!(again, c, "command written as {bytes:?}");
        }
    }

    let terminators = data.iter().filter(|&&b| b == b'\r' || b == 0x07).count();
    let (mut whole, mut pieces) = (Vec::new(), Vec::new());
    let mut d = MessageDecoder::new();
    d.feed(data, &mut whole);
    let mut d2 = MessageDecoder::new();
    crate::chunked(data, seed, |c| d2.feed(c, &mut pieces));
    assert_eq!(whole, pieces, "the chunking changed the messages");
    assert_eq!(d.malformed(), d2.malformed());
    assert!(whole.len() <= terminators);

    let (mut whole, mut pieces) = (Vec::new(), Vec::new());
    let mut d = CommandDecoder::new();
    d.feed(data, &mut whole);
    let mut d2 = CommandDecoder::new();
    crate::chunked(data, seed, |c| d2.feed(c, &mut pieces));
    assert_eq!(whole, pieces, "the chunking changed the commands");
    assert!(whole.len() <= terminators);
}
