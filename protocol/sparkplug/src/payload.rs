//! The Sparkplug B payload: `sparkplug_b.proto` (proto2) as prost messages, written by
//! hand with the same field numbers and wire types. Parts an edge node of this gateway
//! never sends (DataSet, Template, PropertySet, MetaData, extensions) are not modelled;
//! a decoder skips them as protobuf skips unknown fields.

use prost::Message;

/// `message Payload`.
#[derive(Clone, PartialEq, Message)]
pub struct Payload {
    /// Milliseconds since the Unix epoch (UTC) when the message was made.
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<Metric>,
    /// 0..255; absent in NDEATH.
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
    #[prost(string, optional, tag = "4")]
    pub uuid: Option<String>,
    #[prost(bytes = "vec", optional, tag = "5")]
    pub body: Option<Vec<u8>>,
}

/// `message Payload.Metric`.
#[derive(Clone, PartialEq, Message)]
pub struct Metric {
    #[prost(string, optional, tag = "1")]
    pub name: Option<String>,
    #[prost(uint64, optional, tag = "2")]
    pub alias: Option<u64>,
    /// Milliseconds since the Unix epoch (UTC) of the value.
    #[prost(uint64, optional, tag = "3")]
    pub timestamp: Option<u64>,
    /// A [`DataType`] code.
    #[prost(uint32, optional, tag = "4")]
    pub datatype: Option<u32>,
    /// The value is not live (sent late, e.g. kept while the broker was unreachable).
    #[prost(bool, optional, tag = "5")]
    pub is_historical: Option<bool>,
    #[prost(bool, optional, tag = "6")]
    pub is_transient: Option<bool>,
    #[prost(bool, optional, tag = "7")]
    pub is_null: Option<bool>,
    #[prost(oneof = "MetricValue", tags = "10, 11, 12, 13, 14, 15, 16")]
    pub value: Option<MetricValue>,
}

/// `oneof value` of a metric (the scalar members).
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum MetricValue {
    /// Int8, Int16, Int32 (two's complement in 32 bits), UInt8, UInt16, UInt32.
    #[prost(uint32, tag = "10")]
    IntValue(u32),
    /// Int64 (two's complement), UInt64, DateTime (ms since the epoch).
    #[prost(uint64, tag = "11")]
    LongValue(u64),
    #[prost(float, tag = "12")]
    FloatValue(f32),
    #[prost(double, tag = "13")]
    DoubleValue(f64),
    #[prost(bool, tag = "14")]
    BooleanValue(bool),
    /// String, Text, UUID.
    #[prost(string, tag = "15")]
    StringValue(String),
    #[prost(bytes, tag = "16")]
    BytesValue(Vec<u8>),
}

/// `enum DataType` (the codes of Sparkplug B 3.0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum DataType {
    Unknown = 0,
    Int8 = 1,
    Int16 = 2,
    Int32 = 3,
    Int64 = 4,
    UInt8 = 5,
    UInt16 = 6,
    UInt32 = 7,
    UInt64 = 8,
    Float = 9,
    Double = 10,
    Boolean = 11,
    String = 12,
    DateTime = 13,
    Text = 14,
    Uuid = 15,
    DataSet = 16,
    Bytes = 17,
    File = 18,
    Template = 19,
}

impl Metric {
    fn with(name: &str, datatype: DataType, value: MetricValue) -> Metric {
        Metric {
            name: Some(name.to_string()),
            datatype: Some(datatype as u32),
            value: Some(value),
            ..Metric::default()
        }
    }

    pub fn uint64(name: &str, v: u64) -> Metric {
        Metric::with(name, DataType::UInt64, MetricValue::LongValue(v))
    }

    /// Int64 as the specification stores it: two's complement in the uint64 field.
    pub fn int64(name: &str, v: i64) -> Metric {
        Metric::with(name, DataType::Int64, MetricValue::LongValue(v as u64))
    }

    pub fn double(name: &str, v: f64) -> Metric {
        Metric::with(name, DataType::Double, MetricValue::DoubleValue(v))
    }

    pub fn boolean(name: &str, v: bool) -> Metric {
        Metric::with(name, DataType::Boolean, MetricValue::BooleanValue(v))
    }

    pub fn string(name: &str, v: &str) -> Metric {
        Metric::with(name, DataType::String, MetricValue::StringValue(v.into()))
    }

    /// DateTime: milliseconds since the Unix epoch, UTC.
    pub fn datetime(name: &str, ms: u64) -> Metric {
        Metric::with(name, DataType::DateTime, MetricValue::LongValue(ms))
    }

    /// A metric of `datatype` with no value (`is_null`), e.g. a job id while idle.
    pub fn null(name: &str, datatype: DataType) -> Metric {
        Metric {
            name: Some(name.to_string()),
            datatype: Some(datatype as u32),
            is_null: Some(true),
            ..Metric::default()
        }
    }

    /// The value as an Int64 metric holds it.
    pub fn as_i64(&self) -> Option<i64> {
        match self.value {
            Some(MetricValue::LongValue(v)) => Some(v as i64),
            _ => None,
        }
    }
}

impl Payload {
    pub fn encode_to_bytes(&self) -> Vec<u8> {
        self.encode_to_vec()
    }

    /// Decodes a payload from the network; malformed bytes are an error, never a panic.
    pub fn decode_bytes(bytes: &[u8]) -> Result<Payload, prost::DecodeError> {
        Payload::decode(bytes)
    }

    /// The metric named `name`, if present.
    pub fn metric(&self, name: &str) -> Option<&Metric> {
        self.metrics
            .iter()
            .find(|m| m.name.as_deref() == Some(name))
    }
}
