//! MQTT Sparkplug B northbound (being built; see issue 15).
