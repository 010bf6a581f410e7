//! Sparkplug B topics: `spBv1.0/{group_id}/{message_type}/{edge_node_id}[/{device_id}]`.

use std::fmt;

/// The namespace of Sparkplug B.
pub const NAMESPACE: &str = "spBv1.0";

/// The message types of an edge node's topics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MessageType {
    NBirth,
    NDeath,
    DBirth,
    DDeath,
    NData,
    DData,
    NCmd,
    DCmd,
}

impl MessageType {
    pub fn as_str(self) -> &'static str {
        match self {
            MessageType::NBirth => "NBIRTH",
            MessageType::NDeath => "NDEATH",
            MessageType::DBirth => "DBIRTH",
            MessageType::DDeath => "DDEATH",
            MessageType::NData => "NDATA",
            MessageType::DData => "DDATA",
            MessageType::NCmd => "NCMD",
            MessageType::DCmd => "DCMD",
        }
    }

    fn parse(s: &str) -> Option<MessageType> {
        Some(match s {
            "NBIRTH" => MessageType::NBirth,
            "NDEATH" => MessageType::NDeath,
            "DBIRTH" => MessageType::DBirth,
            "DDEATH" => MessageType::DDeath,
            "NDATA" => MessageType::NData,
            "DDATA" => MessageType::DData,
            "NCMD" => MessageType::NCmd,
            "DCMD" => MessageType::DCmd,
            _ => return None,
        })
    }

    /// Whether the topic names a device (D...) rather than the node (N...).
    pub fn is_device(self) -> bool {
        matches!(
            self,
            MessageType::DBirth | MessageType::DDeath | MessageType::DData | MessageType::DCmd
        )
    }
}

/// A parsed or built topic.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Topic {
    pub group_id: String,
    pub message_type: MessageType,
    pub edge_node_id: String,
    /// Present exactly for the device message types.
    pub device_id: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TopicError {
    #[error("{what} `{id}`: an id must not be empty nor hold `+`, `#` or `/`")]
    BadId { what: &'static str, id: String },
    #[error("`{0}` is not a Sparkplug B topic (spBv1.0/GROUP/TYPE/EDGE[/DEVICE])")]
    NotSparkplug(String),
    #[error("`{topic}`: {why}")]
    Shape { topic: String, why: &'static str },
}

/// Checks a group, edge node or device id (UTF-8, non-empty, none of `+ # /`).
pub fn check_id(what: &'static str, id: &str) -> Result<(), TopicError> {
    if id.is_empty() || id.contains(['+', '#', '/']) {
        return Err(TopicError::BadId {
            what,
            id: id.to_string(),
        });
    }
    Ok(())
}

impl Topic {
    /// A node topic (NBIRTH, NDEATH, NDATA, NCMD).
    pub fn node(group: &str, message_type: MessageType, edge: &str) -> Result<Topic, TopicError> {
        check_id("group id", group)?;
        check_id("edge node id", edge)?;
        if message_type.is_device() {
            return Err(TopicError::Shape {
                topic: format!("{NAMESPACE}/{group}/{}/{edge}", message_type.as_str()),
                why: "a device message type needs a device id",
            });
        }
        Ok(Topic {
            group_id: group.into(),
            message_type,
            edge_node_id: edge.into(),
            device_id: None,
        })
    }

    /// A device topic (DBIRTH, DDEATH, DDATA, DCMD).
    pub fn device(
        group: &str,
        message_type: MessageType,
        edge: &str,
        device: &str,
    ) -> Result<Topic, TopicError> {
        check_id("group id", group)?;
        check_id("edge node id", edge)?;
        check_id("device id", device)?;
        if !message_type.is_device() {
            return Err(TopicError::Shape {
                topic: format!(
                    "{NAMESPACE}/{group}/{}/{edge}/{device}",
                    message_type.as_str()
                ),
                why: "a node message type takes no device id",
            });
        }
        Ok(Topic {
            group_id: group.into(),
            message_type,
            edge_node_id: edge.into(),
            device_id: Some(device.into()),
        })
    }

    /// Parses a topic from the network.
    pub fn parse(topic: &str) -> Result<Topic, TopicError> {
        let parts: Vec<&str> = topic.split('/').collect();
        if parts.first() != Some(&NAMESPACE) || !(4..=5).contains(&parts.len()) {
            return Err(TopicError::NotSparkplug(topic.to_string()));
        }
        let message_type = MessageType::parse(parts[2]).ok_or_else(|| TopicError::Shape {
            topic: topic.to_string(),
            why: "unknown message type",
        })?;
        match parts.get(4) {
            Some(device) => Topic::device(parts[1], message_type, parts[3], device),
            None => Topic::node(parts[1], message_type, parts[3]),
        }
    }
}

impl fmt::Display for Topic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{NAMESPACE}/{}/{}/{}",
            self.group_id,
            self.message_type.as_str(),
            self.edge_node_id
        )?;
        if let Some(d) = &self.device_id {
            write!(f, "/{d}")?;
        }
        Ok(())
    }
}
