//! Sparkplug B 3.0 payloads and topics (being built; see issue 15).
