//! What the `dxf` crate's writer leaves for other software to trip on, put right on the
//! written text (its code/value pairs):
//!
//! - a BLOCK and its ENDBLK written with one handle: every object whose handle an earlier
//!   object already has (the ENDBLK, or anything the drawing repeated) gets a new one,
//!   above every handle in the file, and `$HANDSEED` moves past them;
//! - a block record added again for every block of a drawing that was read (so a DXF read
//!   and written back repeats `*Model_Space`, `*Paper_Space` and each block's record):
//!   the BLOCK_RECORD table keeps the first record of each name (names compare without
//!   case, as DXF's symbol tables do);
//! - a LAYOUT object written without its AcDbPlotSettings subclass marker (the crate
//!   drops the plot settings it read): readers that take subclasses in order then read
//!   the AcDbLayout values as plot settings and find no block record for the layout; the
//!   marker is put back before AcDbLayout (the plot settings take their defaults).
//! - an MLINESTYLE written without its line elements (the crate reads them and writes
//!   none: `71 0`): the elements the drawing had, kept from the text read
//!   ([`mline_elements`]), go back after its `71`.
//!
//! Everything else is written as the crate wrote it, byte for byte.

use std::collections::{HashMap, HashSet};

/// Per MLINESTYLE handle (upper case): its element count and the element pairs
/// (codes 49, 62, 6) as the file had them.
pub(crate) type MlineElements = HashMap<String, Elements>;

/// An MLINESTYLE's element count and its element pairs.
pub(crate) type Elements = (String, Vec<(String, String)>);

/// One `0` group: its type and the range of pairs it spans.
struct Object {
    kind: Vec<u8>,
    start: usize,
    end: usize,
}

fn trim(s: &[u8]) -> &[u8] {
    let s = s.strip_suffix(b"\r").unwrap_or(s);
    let a = s
        .iter()
        .position(|c| !c.is_ascii_whitespace())
        .unwrap_or(s.len());
    let b = s
        .iter()
        .rposition(|c| !c.is_ascii_whitespace())
        .map_or(a, |b| b + 1);
    &s[a..b.max(a)]
}

fn hex(s: &[u8]) -> Option<u64> {
    u64::from_str_radix(std::str::from_utf8(s).ok()?, 16).ok()
}

/// The code/value pairs of a DXF text (codes trimmed, values without their CR), or None
/// when it is not pairs of lines (a binary DXF).
fn pairs_of(bytes: &[u8]) -> Option<Vec<(&[u8], &[u8])>> {
    let mut lines: Vec<&[u8]> = bytes.split(|&c| c == b'\n').collect();
    if lines.last().is_some_and(|l| l.is_empty()) {
        lines.pop();
    }
    if !lines.len().is_multiple_of(2) {
        return None;
    }
    Some(
        lines
            .chunks(2)
            .map(|c| (trim(c[0]), c[1].strip_suffix(b"\r").unwrap_or(c[1])))
            .collect(),
    )
}

/// The line elements of every MLINESTYLE in a DXF text read (see the module's notes).
pub(crate) fn mline_elements(bytes: &[u8]) -> MlineElements {
    let mut out = MlineElements::new();
    let Some(pairs) = pairs_of(bytes) else {
        return out;
    };
    let text = |v: &[u8]| String::from_utf8_lossy(trim(v)).into_owned();
    let mut k = 0;
    while k < pairs.len() {
        if pairs[k].0 == b"0" && trim(pairs[k].1) == b"MLINESTYLE" {
            let end = (k + 1..pairs.len())
                .find(|&j| pairs[j].0 == b"0")
                .unwrap_or(pairs.len());
            let body = &pairs[k + 1..end];
            let handle = body.iter().find(|(c, _)| *c == b"5").map(|(_, v)| text(v));
            if let (Some(h), Some(at)) = (handle, body.iter().position(|(c, _)| *c == b"71")) {
                let elements: Vec<(String, String)> = body[at + 1..]
                    .iter()
                    .take_while(|(c, _)| matches!(*c, b"49" | b"62" | b"6"))
                    .map(|(c, v)| (text(c), text(v)))
                    .collect();
                if !elements.is_empty() {
                    out.insert(h.to_ascii_uppercase(), (text(body[at].1), elements));
                }
            }
            k = end;
        } else {
            k += 1;
        }
    }
    out
}

/// The written DXF text put right (see the module's notes), with the MLINESTYLE
/// elements of the drawing read. A text that is not pairs of lines is returned as it is.
pub(crate) fn tidy(bytes: Vec<u8>, mlines: &MlineElements) -> Vec<u8> {
    let newline: &[u8] = if bytes.windows(2).any(|w| w == b"\r\n") {
        b"\r\n"
    } else {
        b"\n"
    };
    let mut lines: Vec<&[u8]> = bytes.split(|&c| c == b'\n').collect();
    if lines.last().is_some_and(|l| l.is_empty()) {
        lines.pop();
    }
    if !lines.len().is_multiple_of(2) {
        return bytes;
    }
    let pairs: Vec<(&[u8], &[u8])> = lines
        .chunks(2)
        .map(|c| (trim(c[0]), c[1].strip_suffix(b"\r").unwrap_or(c[1])))
        .collect();
    let is_handle = |code: &[u8]| code == b"5" || code == b"105";
    let top = pairs
        .iter()
        .filter(|(c, _)| is_handle(c))
        .filter_map(|(_, v)| hex(trim(v)))
        .max()
        .unwrap_or(0);
    // The objects, each from its `0` pair to the next.
    let mut objects: Vec<Object> = Vec::new();
    for (i, (c, v)) in pairs.iter().enumerate() {
        if *c == b"0" {
            if let Some(o) = objects.last_mut() {
                o.end = i;
            }
            objects.push(Object {
                kind: trim(v).to_vec(),
                start: i,
                end: pairs.len(),
            });
        }
    }
    let mut drop = vec![false; pairs.len()];
    let mut replace: Vec<Option<String>> = vec![None; pairs.len()];
    // Pairs after which an MLINESTYLE's elements go (its `71`, with the count).
    let mut elements_after: HashMap<usize, &Elements> = HashMap::new();
    // Pairs before which `100 AcDbPlotSettings` goes.
    let mut plot_settings = vec![false; pairs.len()];
    let mut next = top + 1;
    let mut seen_handles: HashSet<u64> = HashSet::new();
    let mut seen_records: HashSet<Vec<u8>> = HashSet::new();
    let mut table: Vec<u8> = Vec::new();
    for o in &objects {
        let body = &pairs[o.start + 1..o.end];
        let name = body.iter().find(|(c, _)| *c == b"2").map(|(_, v)| trim(v));
        if o.kind == b"TABLE" {
            table = name.unwrap_or_default().to_vec();
        } else if o.kind == b"ENDTAB" {
            table.clear();
        }
        if o.kind == b"BLOCK_RECORD" && table == b"BLOCK_RECORD" {
            if let Some(n) = name {
                if !seen_records.insert(n.to_ascii_uppercase()) {
                    drop[o.start..o.end].iter_mut().for_each(|d| *d = true);
                    continue;
                }
            }
        }
        if o.kind == b"LAYOUT"
            && !body
                .iter()
                .any(|(c, v)| *c == b"100" && trim(v) == b"AcDbPlotSettings")
        {
            if let Some(k) = (o.start + 1..o.end)
                .find(|&k| pairs[k].0 == b"100" && trim(pairs[k].1) == b"AcDbLayout")
            {
                plot_settings[k] = true;
            }
        }
        if o.kind == b"MLINESTYLE" {
            let handle = body.iter().find(|(c, _)| *c == b"5").map(|(_, v)| trim(v));
            let at = (o.start + 1..o.end).find(|&k| pairs[k].0 == b"71");
            let written = at.is_some_and(|k| pairs.get(k + 1).is_some_and(|p| p.0 == b"49"));
            if let (Some(h), Some(k), false) = (handle, at, written) {
                if let Some(e) = mlines.get(&String::from_utf8_lossy(h).to_ascii_uppercase()) {
                    elements_after.insert(k, e);
                }
            }
        }
        // The object's own handle: its first 5 (or 105, DIMSTYLE's) pair.
        if let Some(k) = (o.start + 1..o.end).find(|&k| is_handle(pairs[k].0)) {
            if let Some(h) = hex(trim(pairs[k].1)) {
                if !seen_handles.insert(h) {
                    replace[k] = Some(format!("{next:X}"));
                    seen_handles.insert(next);
                    next += 1;
                }
            }
        }
    }
    // $HANDSEED past every handle.
    if let Some(k) = pairs
        .iter()
        .position(|(c, v)| *c == b"9" && trim(v) == b"$HANDSEED")
    {
        if pairs.get(k + 1).is_some_and(|(c, _)| *c == b"5") {
            replace[k + 1] = Some(format!("{next:X}"));
        }
    }
    let mut out = Vec::with_capacity(bytes.len());
    for (i, chunk) in lines.chunks(2).enumerate() {
        if drop[i] {
            continue;
        }
        if plot_settings[i] {
            out.extend_from_slice(b"100");
            out.extend_from_slice(newline);
            out.extend_from_slice(b"AcDbPlotSettings");
            out.extend_from_slice(newline);
        }
        out.extend_from_slice(chunk[0]);
        out.push(b'\n');
        let elements = elements_after.get(&i);
        match (&replace[i], elements) {
            (_, Some((count, _))) => {
                out.extend_from_slice(count.as_bytes());
                out.extend_from_slice(newline);
            }
            (Some(v), None) => {
                out.extend_from_slice(v.as_bytes());
                out.extend_from_slice(newline);
            }
            (None, None) => {
                out.extend_from_slice(chunk[1]);
                out.push(b'\n');
            }
        }
        for (code, value) in elements.map(|e| e.1.as_slice()).unwrap_or_default() {
            out.extend_from_slice(format!("{code:>3}").as_bytes());
            out.extend_from_slice(newline);
            out.extend_from_slice(value.as_bytes());
            out.extend_from_slice(newline);
        }
    }
    out
}
