//! LinuxCNC: the replies of linuxcncrsh through the driver's line splitter and reply
//! reader.

use drivers::linuxcnc::reply::{numbers, LineSplitter, Reply, MAX_LINE};

/// Bytes from linuxcncrsh: the splitter fed whole and in small chunks gives the same
/// lines, none empty and none over `MAX_LINE`; every line reads as a reply, and a
/// position's numbers are finite.
pub fn linuxcnc_reply(data: &[u8]) {
    let Some((&seed, data)) = data.split_first() else {
        return;
    };
    let mut whole = Vec::new();
    LineSplitter::new().feed(data, &mut whole);
    let mut pieces = Vec::new();
    let mut s = LineSplitter::new();
    crate::chunked(data, seed, |c| s.feed(c, &mut pieces));
    assert_eq!(whole, pieces, "the chunking changed the lines");
    assert!(whole.len() <= data.len());
    for l in &whole {
        assert!(
            l.text.len() <= 3 * MAX_LINE,
            "lossy UTF-8 at most triples a byte"
        );
        assert!(!l.text.is_empty() || l.cut);
        assert!(!l.text.contains(['\r', '\n']));
        if let Reply::Value { words, .. } = Reply::parse(&l.text) {
            if let Some(v) = numbers(&words) {
                assert!(v.iter().all(|x| x.is_finite()));
            }
        }
    }
}
