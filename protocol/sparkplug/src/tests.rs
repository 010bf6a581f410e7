use super::*;

/// NBIRTH's bdSeq metric, byte for byte as protobuf's wire format lays it out (keys are
/// `(field << 3) | wire type`; varints; length-delimited messages).
#[test]
fn a_payload_is_encoded_as_the_wire_format_says() {
    let p = Payload {
        timestamp: Some(1),
        metrics: vec![Metric::uint64("bdSeq", 4)],
        seq: Some(0),
        ..Payload::default()
    };
    let want: Vec<u8> = vec![
        0x08, 0x01, // field 1 timestamp, varint 1
        0x12, 0x0B, // field 2 metrics, 11 bytes:
        0x0A, 0x05, b'b', b'd', b'S', b'e', b'q', // field 1 name
        0x20, 0x08, // field 4 datatype = 8 (UInt64)
        0x58, 0x04, // field 11 long_value = 4
        0x18, 0x00, // field 3 seq = 0 (present: NBIRTH's seq is 0, not absent)
    ];
    assert_eq!(p.encode_to_bytes(), want);
    assert_eq!(Payload::decode_bytes(&want).unwrap(), p);
}

#[test]
fn doubles_are_fixed64_and_negative_int64_is_twos_complement() {
    let m = Metric::double("x", 1.5);
    let p = Payload {
        metrics: vec![m],
        ..Payload::default()
    };
    let bytes = p.encode_to_bytes();
    assert_eq!(
        bytes,
        vec![
            0x12, 0x0E, 0x0A, 0x01, b'x', 0x20, 0x0A, // name, datatype 10 (Double)
            0x69, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xF8, 0x3F, // field 13, fixed64 1.5
        ]
    );
    let m = Metric::int64("j", -1);
    assert_eq!(m.datatype, Some(DataType::Int64 as u32));
    let back = Payload::decode_bytes(
        &Payload {
            metrics: vec![m],
            ..Payload::default()
        }
        .encode_to_bytes(),
    )
    .unwrap();
    assert_eq!(back.metrics[0].as_i64(), Some(-1));
}

#[test]
fn unknown_fields_are_skipped_and_garbage_is_an_error() {
    // A metric with a DataSet (field 17) this crate does not model, then a boolean.
    let bytes = [
        0x12, 0x0C, 0x0A, 0x01, b'd', 0x8A, 0x01, 0x02, 0x08, 0x00, // field 17: 2 bytes
        0x20, 0x0B, 0x70, 0x01, // datatype 11 (Boolean), field 14 = true
    ];
    let p = Payload::decode_bytes(&bytes).unwrap();
    assert_eq!(p.metrics[0].name.as_deref(), Some("d"));
    assert_eq!(p.metrics[0].value, Some(MetricValue::BooleanValue(true)));
    assert!(Payload::decode_bytes(&[0x12, 0x20, 0x0A]).is_err());
    assert!(Payload::decode_bytes(&[0xFF; 11]).is_err());
}

#[test]
fn rebirth_is_asked_only_by_the_metric_set_true() {
    let ask = |v: bool| Payload {
        metrics: vec![Metric::boolean(REBIRTH, v)],
        ..Payload::default()
    };
    assert!(asks_rebirth(&ask(true)));
    assert!(!asks_rebirth(&ask(false)));
    assert!(!asks_rebirth(&Payload {
        metrics: vec![Metric::uint64(REBIRTH, 1)],
        ..Payload::default()
    }));
}

#[test]
fn seq_restarts_at_each_birth_and_wraps_after_255() {
    let mut s = EdgeSequence::default();
    assert_eq!(s.birth(), 0);
    assert_eq!(s.next_seq(), 1);
    for _ in 2..=255 {
        s.next_seq();
    }
    assert_eq!(s.next_seq(), 0, "255 is followed by 0");
    assert_eq!(s.next_seq(), 1);
    assert_eq!(s.birth(), 0);
    assert_eq!(s.next_seq(), 1);
    assert_eq!(next_bdseq(None), 0);
    assert_eq!(next_bdseq(Some(7)), 8);
    assert_eq!(next_bdseq(Some(255)), 0);
}

#[test]
fn topics_are_built_parsed_and_checked() {
    let t = Topic::device("plant-a", MessageType::DData, "box-1", "mill-3").unwrap();
    assert_eq!(t.to_string(), "spBv1.0/plant-a/DDATA/box-1/mill-3");
    assert_eq!(Topic::parse(&t.to_string()).unwrap(), t);
    let n = Topic::node("plant-a", MessageType::NCmd, "box-1").unwrap();
    assert_eq!(n.to_string(), "spBv1.0/plant-a/NCMD/box-1");
    assert_eq!(Topic::parse("spBv1.0/plant-a/NCMD/box-1").unwrap(), n);
    for bad in ["a+b", "a#", "a/b", ""] {
        assert!(matches!(
            Topic::node(bad, MessageType::NBirth, "e"),
            Err(TopicError::BadId { .. })
        ));
    }
    assert!(
        Topic::parse("spBv1.0/g/DDATA/e").is_err(),
        "DDATA needs a device"
    );
    assert!(
        Topic::parse("spBv1.0/g/NDATA/e/d").is_err(),
        "NDATA takes none"
    );
    assert!(Topic::parse("spBv1.0/g/XDATA/e").is_err());
    assert!(Topic::parse("spAv1.0/g/NCMD/e").is_err());
    assert!(Topic::parse("spBv1.0/g/NCMD/e/d/x").is_err());
}
