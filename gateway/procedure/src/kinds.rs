//! The registry: every capability's [`Procedure`](crate::registry::Procedure) in one list,
//! and the requests of any kind parsed through it. A new capability is one module and
//! one line in [`KINDS`].

use crate::registry::{entry, Kind};
use crate::request::*;
use serde_json::Value;
use utoipa::openapi::schema::Schema;
use utoipa::openapi::RefOr;

/// Every capability, in the order the page offers them.
pub static KINDS: &[Kind] = &[
    entry::<crate::compensate::Compensate>(),
    entry::<crate::map::Map>(),
    entry::<crate::reference::Reference>(),
    entry::<crate::verify::Verify>(),
    entry::<crate::iso230::Iso230>(),
    entry::<crate::iso230::Iso230Evaluate>(),
    entry::<crate::export::Export>(),
    entry::<crate::rewrite::Rewrite>(),
    entry::<crate::layout::LayoutPartition>(),
    entry::<crate::rotary::RotaryMeasure>(),
    entry::<crate::rotary::RotaryIdentify>(),
    entry::<crate::rotary::RotaryRewrite>(),
    entry::<crate::cut::Cut>(),
    entry::<crate::volumetric::VolumetricIdentify>(),
    entry::<crate::volumetric::VolumetricEval>(),
    entry::<crate::volumetric::VolumetricContributions>(),
    entry::<crate::volumetric::VolumetricCampaign>(),
    entry::<crate::volumetric::VolumetricExportIsg>(),
    entry::<crate::board::BoardMake>(),
    entry::<crate::localize::Localize>(),
    entry::<crate::dnc::Dnc>(),
    entry::<crate::proxy::PassThrough>(),
];

/// The kind named `name`.
pub fn find(name: &str) -> Option<&'static Kind> {
    KINDS.iter().find(|k| k.name == name)
}

/// The kind named `name`, or the error the API answers (naming every kind).
pub fn kind(name: &str) -> Result<&'static Kind, RequestError> {
    find(name).ok_or_else(|| {
        RequestError::new(
            "kind",
            format!(
                "unknown job kind {name:?}; this service runs: {}",
                KINDS.iter().map(|k| k.name).collect::<Vec<_>>().join(", ")
            ),
        )
    })
}

/// The text a person reads of a job kind's result (the CLI's summary; the page shows it
/// above the result's numbers).
pub fn summary(kind: &str, result: &Value) -> Option<String> {
    find(kind).map(|k| k.summary(result))
}

/// Each kind's params schema, `(kind, schema)`: the service's OpenAPI document names
/// them `job.<kind>`, and the page builds its forms from them.
pub fn schemas() -> Vec<(&'static str, RefOr<Schema>)> {
    KINDS.iter().map(|k| (k.name, k.schema())).collect()
}

/// A checked request of any registered kind ([`KINDS`]): the kind and
/// its params with every default written out (what the service stores, so a stored job
/// says exactly what it asked for).
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    kind: &'static Kind,
    params: Value,
}

/// The kinds [`Request::parse`] knows: every registered procedure.
pub fn kinds() -> impl Iterator<Item = &'static str> {
    KINDS.iter().map(|k| k.name)
}

impl Request {
    /// Parses and checks a request: `kind` and its `params` object. Unknown kinds and
    /// fields are refused, every bound checked, the field named.
    pub fn parse(name: &str, params: &Value) -> Result<Request, RequestError> {
        let kind = kind(name)?;
        Ok(Request {
            kind,
            params: kind.parse(params)?,
        })
    }

    /// The request as its params object, every default written out.
    pub fn params(&self) -> Value {
        self.params.clone()
    }

    pub fn kind(&self) -> &'static str {
        self.kind.name
    }

    /// The registered kind.
    pub fn registered(&self) -> &'static Kind {
        self.kind
    }

    /// Whether the request uses the machine's active error map.
    pub fn uses_map(&self) -> bool {
        self.kind.uses_map(&self.params)
    }
}

/// Each request's bounds, checked once where it is parsed
/// ([`Checked`](crate::registry::Checked)).
macro_rules! checked {
    ($($t:ty),* $(,)?) => {
        $(impl crate::registry::Checked for $t {
            fn check(&self) -> Result<(), RequestError> {
                <$t>::check(self)
            }
        })*
    };
}

checked!(
    CompensateRequest,
    MapRequest,
    VerifyRequest,
    Iso230Request,
    LayoutRequest,
    CutRequest,
    RotaryRequest,
    ReferenceRequest,
);
