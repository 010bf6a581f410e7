//! Every capability as one [`Procedure`], and the registry ([`KINDS`]) from which the
//! command line's commands, the service's job kinds, the forms' JSON schemas, the
//! summaries and the worker's dispatch all come. A new capability is one module that
//! implements [`Procedure`] and one line in [`KINDS`]; the tests of this module and of
//! the front ends fail when a registered kind lacks a schema, a summary, a command or a
//! job kind.

use crate::command_line::FileArg;
use crate::context::Context;
use crate::request::{from_json, RequestError};
use crate::Outcome;
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::Value;
use std::future::Future;
use std::pin::Pin;
use utoipa::openapi::schema::Schema;
use utoipa::openapi::RefOr;

/// A request's command-line flags: its fields (`clap::Args`) in the `gateway` binary
/// (the `cli` feature); nothing elsewhere.
#[cfg(feature = "cli")]
pub trait Flags: clap::Args {}
#[cfg(feature = "cli")]
impl<T: clap::Args> Flags for T {}
/// A request's command-line flags (none without the `cli` feature).
#[cfg(not(feature = "cli"))]
pub trait Flags {}
#[cfg(not(feature = "cli"))]
impl<T> Flags for T {}

/// A request whose bounds are checked once, where it is parsed.
pub trait Checked {
    fn check(&self) -> Result<(), RequestError>;
}

/// What a kind of job needs from the machine it runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Uses {
    /// The X-Y stage and camera of the machine's job file.
    pub devices: bool,
    /// The error map (the service: the machine's active `error_map` profile).
    pub map: MapUse,
    /// The rotary table's job file.
    pub rotary: bool,
    /// The machine's controller link itself (the pass-through opens its port): the
    /// service closes the machine's devices before the job and opens them after.
    pub link: bool,
}

/// Whether a kind applies an error map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapUse {
    Never,
    Always,
    /// When the request says so (ISO 230-2's `with_map`).
    WhenAsked,
}

impl Uses {
    /// Nothing from the machine: files in, files out.
    pub const NOTHING: Uses = Uses {
        devices: false,
        map: MapUse::Never,
        rotary: false,
        link: false,
    };
    /// The stage and the camera.
    pub const DEVICES: Uses = Uses {
        devices: true,
        map: MapUse::Never,
        rotary: false,
        link: false,
    };
    /// The stage, the camera and the error map.
    pub const DEVICES_AND_MAP: Uses = Uses {
        devices: true,
        map: MapUse::Always,
        rotary: false,
        link: false,
    };
    /// The error map alone.
    pub const MAP: Uses = Uses {
        devices: false,
        map: MapUse::Always,
        rotary: false,
        link: false,
    };
    /// The machine's controller link, opened by the kind itself; the error map when the
    /// request asks for it.
    pub const LINK: Uses = Uses {
        devices: false,
        map: MapUse::WhenAsked,
        rotary: false,
        link: true,
    };
    /// The rotary table.
    pub const ROTARY: Uses = Uses {
        devices: false,
        map: MapUse::Never,
        rotary: true,
        link: false,
    };
}

/// What the service knows of a machine when a job is queued, so a request can be
/// refused before it waits in the queue.
#[derive(Debug, Clone, Default)]
pub struct Facts {
    /// The area a map scan covers (from the stage's soft limits and the board).
    pub scan_area: Option<([f64; 2], [f64; 2])>,
}

/// One capability.
#[allow(async_fn_in_trait)]
pub trait Procedure {
    /// The job kind (the service) and the key of the command (the CLI).
    const KIND: &'static str;
    /// One line for the form's title and the command's help.
    const TITLE: &'static str;
    /// The command line's words for it (`rotary identify`).
    const COMMAND: &'static str;
    /// What an operator calls it, in lists and headings ("Error map scan"): the schema's
    /// `title`.
    const LABEL: &'static str;
    /// What it does, written for the shop floor (no flags, no developers' terms): the
    /// schema's `x-help`, shown above its form.
    const HELP: &'static str;
    /// Shop-floor help of its fields where their documentation speaks to developers
    /// (`(field, help)`): each field's `x-help` in the schema, shown under it.
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[];
    /// What it needs of the machine.
    const USES: Uses;
    /// Its request: the CLI's flags and the API's params, checked once.
    type Request: Serialize + DeserializeOwned + utoipa::ToSchema + Checked + Flags;
    /// The command line's file arguments: each read into the request or named for the
    /// files context ([`crate::command_line`]).
    const FILES: &'static [FileArg] = &[];
    /// What the command line's progress bar counts ("frames"); empty: no bar.
    const STEPS: &'static str = "";
    /// Its result: the object `--json` prints, the store keeps and the page shows (also
    /// what was done so far when it stopped).
    type Result: Serialize + DeserializeOwned + utoipa::ToSchema;
    /// The command's exit code for a result: 0, or 2 for a verdict the shop acts on (a
    /// drifted map, a model unfit for compensation).
    fn exit_code(_result: &Self::Result) -> u8 {
        0
    }
    /// Runs it.
    async fn run(request: Self::Request, cx: &mut dyn Context) -> Outcome<Self::Result>;
    /// The result as a person reads it (the CLI's text, the page's summary).
    fn summary(result: &Self::Result) -> String;
    /// Request fields only the command line sets: real ports on the box the command runs
    /// on. The service refuses them when queued ([`Self::admit`]) and its forms do not
    /// show them (the schema marks them `x-command-line-only`).
    const COMMAND_LINE_ONLY: &'static [&'static str] = &[];
    /// A refusal at queue time from what the machine knows (default: none).
    fn admit(_request: &Self::Request, _facts: &Facts) -> Result<(), RequestError> {
        Ok(())
    }
    /// Whether a request uses the error map (by default: what [`Self::USES`] says).
    fn uses_map(_request: &Self::Request) -> bool {
        Self::USES.map == MapUse::Always
    }
}

type Run = for<'a> fn(Value, &'a mut dyn Context) -> Pin<Box<dyn Future<Output = Outcome> + 'a>>;

/// A registered capability, its types erased (see [`Procedure`]).
pub struct Kind {
    pub name: &'static str,
    pub title: &'static str,
    pub command: &'static str,
    /// [`Procedure::LABEL`].
    pub label: &'static str,
    /// [`Procedure::HELP`].
    pub help: &'static str,
    /// [`Procedure::FIELD_HELP`].
    pub field_help: &'static [(&'static str, &'static str)],
    pub uses: Uses,
    /// [`Procedure::COMMAND_LINE_ONLY`].
    pub command_line_only: &'static [&'static str],
    parse: fn(&Value) -> Result<Value, RequestError>,
    admit: fn(&Value, &Facts) -> Result<(), RequestError>,
    uses_map: fn(&Value) -> bool,
    run: Run,
    summary: fn(&Value) -> String,
    schema: fn() -> RefOr<Schema>,
    /// [`Procedure::FILES`].
    pub files: &'static [FileArg],
    /// [`Procedure::STEPS`].
    pub steps: &'static str,
    exit_code: fn(&Value) -> u8,
    result_schema: fn() -> RefOr<Schema>,
    referenced: fn(&mut Vec<(String, RefOr<Schema>)>),
    /// The request's flags added to a command.
    #[cfg(feature = "cli")]
    flags: fn(clap::Command) -> clap::Command,
    /// The request the flags give, as params.
    #[cfg(feature = "cli")]
    from_flags: fn(&clap::ArgMatches) -> Result<Value, clap::Error>,
}

impl std::fmt::Debug for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Kind").field("name", &self.name).finish()
    }
}

impl PartialEq for Kind {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
    }
}

fn parse_as<P: Procedure>(params: &Value) -> Result<P::Request, RequestError> {
    if !params.is_object() {
        return Err(RequestError::new("params", "must be a JSON object"));
    }
    let request: P::Request = from_json(params)?;
    request.check()?;
    Ok(request)
}

fn normalized<P: Procedure>(params: &Value) -> Result<Value, RequestError> {
    let request = parse_as::<P>(params)?;
    serde_json::to_value(&request).map_err(|e| RequestError::new("params", e.to_string()))
}

fn admit_as<P: Procedure>(params: &Value, facts: &Facts) -> Result<(), RequestError> {
    P::admit(&parse_as::<P>(params)?, facts)
}

fn uses_map_as<P: Procedure>(params: &Value) -> bool {
    parse_as::<P>(params).is_ok_and(|r| P::uses_map(&r))
}

fn run_as<P: Procedure + 'static>(
    params: Value,
    cx: &mut dyn Context,
) -> Pin<Box<dyn Future<Output = Outcome> + '_>> {
    Box::pin(async move {
        match parse_as::<P>(&params) {
            Ok(request) => P::run(request, cx).await.map_result(|result| {
                // A result that cannot be JSON (a map key that is not a string) is a
                // programming error the registry's tests catch.
                let json =
                    serde_json::to_value(result).expect("a procedure's result serializes to JSON");
                // Every test run of a kind checks that its result reads back (the summary
                // and the exit code read the stored JSON): a field written only sometimes
                // needs its default. A NaN figure is written as null and cannot.
                #[cfg(debug_assertions)]
                if let Err(e) = serde_json::from_value::<P::Result>(json.clone()) {
                    assert!(
                        e.to_string().starts_with("invalid type: null"),
                        "{}: its result does not read back: {e}",
                        P::KIND
                    );
                }
                json
            }),
            // A stored request that no longer parses (a database from an older version).
            Err(e) if e.field == "params" => Outcome::failed(format!("params: {}", e.message)),
            Err(e) => Outcome::failed(format!("params.{e}")),
        }
    })
}

/// A stored result as `P`'s result type, `None` when it is not one (a record written by
/// an older version).
fn result_as<P: Procedure>(result: &Value) -> Option<P::Result> {
    serde_json::from_value(result.clone()).ok()
}

fn summary_as<P: Procedure>(result: &Value) -> String {
    match result_as::<P>(result) {
        Some(r) => P::summary(&r),
        None => format!("(a result this version does not read: {result})"),
    }
}

fn exit_code_as<P: Procedure>(result: &Value) -> u8 {
    result_as::<P>(result).map_or(0, |r| P::exit_code(&r))
}

fn referenced_as<P: Procedure>(schemas: &mut Vec<(String, RefOr<Schema>)>) {
    use utoipa::{PartialSchema, ToSchema};
    <P::Request as ToSchema>::schemas(schemas);
    <P::Result as ToSchema>::schemas(schemas);
    // Under its own name too: a result may hold results of its own kind (a series of
    // checks), which refer to it.
    schemas.push((P::Result::name().into_owned(), P::Result::schema()));
}

/// The registry's entry of `P`.
pub const fn entry<P: Procedure + 'static>() -> Kind {
    Kind {
        name: P::KIND,
        title: P::TITLE,
        command: P::COMMAND,
        label: P::LABEL,
        help: P::HELP,
        field_help: P::FIELD_HELP,
        uses: P::USES,
        command_line_only: P::COMMAND_LINE_ONLY,
        parse: normalized::<P>,
        admit: admit_as::<P>,
        uses_map: uses_map_as::<P>,
        run: run_as::<P>,
        summary: summary_as::<P>,
        schema: <P::Request as utoipa::PartialSchema>::schema,
        files: P::FILES,
        steps: P::STEPS,
        exit_code: exit_code_as::<P>,
        result_schema: <P::Result as utoipa::PartialSchema>::schema,
        referenced: referenced_as::<P>,
        #[cfg(feature = "cli")]
        flags: <P::Request as clap::Args>::augment_args,
        #[cfg(feature = "cli")]
        from_flags: from_flags_as::<P>,
    }
}

#[cfg(feature = "cli")]
fn from_flags_as<P: Procedure>(matches: &clap::ArgMatches) -> Result<Value, clap::Error> {
    let request = <P::Request as clap::FromArgMatches>::from_arg_matches(matches)?;
    serde_json::to_value(&request)
        .map_err(|e| clap::Error::raw(clap::error::ErrorKind::InvalidValue, e))
}

impl Kind {
    /// The params checked, every default written out (what the service stores).
    pub fn parse(&self, params: &Value) -> Result<Value, RequestError> {
        (self.parse)(params)
    }

    /// Refused at queue time from what the machine knows.
    pub fn admit(&self, params: &Value, facts: &Facts) -> Result<(), RequestError> {
        (self.admit)(params, facts)
    }

    /// Whether these params use the error map.
    pub fn uses_map(&self, params: &Value) -> bool {
        (self.uses_map)(params)
    }

    /// Runs a request (its params) in a context.
    pub async fn run(&self, params: Value, cx: &mut dyn Context) -> Outcome {
        (self.run)(params, cx).await
    }

    pub fn summary(&self, result: &Value) -> String {
        (self.summary)(result)
    }

    /// [`Procedure::exit_code`].
    pub fn exit_code(&self, result: &Value) -> u8 {
        (self.exit_code)(result)
    }

    /// The request's flags added to `command`.
    #[cfg(feature = "cli")]
    pub fn flags(&self, command: clap::Command) -> clap::Command {
        (self.flags)(command)
    }

    /// The params the flags of `matches` give (before the files are read into them).
    #[cfg(feature = "cli")]
    pub fn from_flags(&self, matches: &clap::ArgMatches) -> Result<Value, clap::Error> {
        (self.from_flags)(matches)
    }

    /// The JSON schema (OpenAPI 3.1) of its result ([`Procedure::Result`]).
    pub fn result_schema(&self) -> RefOr<Schema> {
        (self.result_schema)()
    }

    /// The named schemas its params' and result's schemas refer to (`$ref`), `(name,
    /// schema)`: an OpenAPI document that has these kinds' schemas has these too.
    pub fn referenced_schemas(&self) -> Vec<(String, RefOr<Schema>)> {
        let mut schemas = Vec::new();
        (self.referenced)(&mut schemas);
        schemas
    }

    /// The JSON schema (OpenAPI 3.1) of its params: the page builds the form from it.
    /// Its `title` is the kind's label and its `x-help` the kind's help; the fields only
    /// the command line sets are marked `x-command-line-only`, and fields with shop-floor
    /// help carry it as `x-help`.
    pub fn schema(&self) -> RefOr<Schema> {
        use utoipa::openapi::extensions::{Extensions, ExtensionsBuilder};
        fn mark(extensions: &mut Option<Extensions>, key: &str, value: Value) {
            let added = ExtensionsBuilder::new().add(key, value).build();
            extensions.get_or_insert_with(Default::default).merge(added);
        }
        let mut schema = (self.schema)();
        if let RefOr::T(Schema::Object(object)) = &mut schema {
            object.title = Some(self.label.to_string());
            mark(&mut object.extensions, "x-help", self.help.into());
            let fields = (self.command_line_only.iter())
                .map(|name| (*name, "x-command-line-only", Value::Bool(true)))
                .chain(
                    (self.field_help.iter()).map(|(name, help)| (*name, "x-help", (*help).into())),
                );
            for (name, key, value) in fields {
                let extensions = match object.properties.get_mut(name) {
                    Some(RefOr::T(Schema::Object(field))) => &mut field.extensions,
                    Some(RefOr::T(Schema::Array(field))) => &mut field.extensions,
                    Some(RefOr::T(Schema::OneOf(field))) => &mut field.extensions,
                    _ => continue,
                };
                mark(extensions, key, value);
            }
        }
        schema
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinds::{find, kind, KINDS};
    use serde_json::json;

    /// Every registered kind is whole: a unique name, a title for its form, a command,
    /// a params schema with its fields (or none, refusing any), and a summary that reads any result (also an
    /// empty one: a failed job's) without panicking.
    #[test]
    fn every_registered_kind_has_what_the_front_ends_take_from_it() {
        let mut names = std::collections::HashSet::new();
        for k in KINDS {
            assert!(names.insert(k.name), "{} registered twice", k.name);
            assert!(!k.title.is_empty() && !k.command.is_empty(), "{}", k.name);
            let schema = serde_json::to_value(k.schema()).unwrap();
            assert_eq!(schema["type"], "object", "{}: {schema}", k.name);
            // Its fields (a kind with nothing to choose has none, and refuses any).
            let fields = schema
                .get("properties")
                .map_or(0, |p| p.as_object().unwrap().len());
            assert!(
                fields > 0 || schema["additionalProperties"] == false,
                "{}: {schema}",
                k.name
            );
            let _ = k.summary(&json!({}));
            assert_eq!(find(k.name), Some(k));
            // A label and shop-floor help for the page, and every field help names a
            // field that is there.
            assert_eq!(schema["title"], k.label, "{}", k.name);
            assert!(!k.label.is_empty() && k.help.len() > 20, "{}", k.name);
            for text in [k.label, k.help]
                .iter()
                .chain(k.field_help.iter().map(|(_, h)| h))
            {
                assert!(
                    !text.contains("--") && !text.to_lowercase().contains("command line"),
                    "{}: {text:?} speaks of the command line",
                    k.name
                );
            }
            // The page reads each field's schema as it is: no field is a bare `$ref`.
            for (name, field) in schema["properties"].as_object().into_iter().flatten() {
                assert!(field.get("$ref").is_none(), "{}.{name}: inline it", k.name);
            }
            for (name, help) in k.field_help {
                assert_eq!(
                    schema["properties"][name]["x-help"], *help,
                    "{}.{name}: no such field, or its help is not carried: {schema}",
                    k.name
                );
            }
            // A command-line-only field is a field, marked, and refused when queued.
            for name in k.command_line_only {
                let field = &schema["properties"][name];
                assert_eq!(
                    field["x-command-line-only"], true,
                    "{}.{name}: {schema}",
                    k.name
                );
            }
        }
        let cut = find("cut").unwrap();
        assert_eq!(cut.command_line_only, ["conveyor", "heads"]);
        let layout = json!({"layout": "{}", "format": "json", "tools": 1, "window_mm": 100.0,
            "gap_mm": 5.0});
        let params = json!({"partition": layout, "conveyor": "/dev/ttyUSB0",
            "heads": ["/dev/ttyUSB1"]});
        let e = cut.admit(&params, &Facts::default()).unwrap_err();
        assert!(cut.command_line_only.contains(&e.field.as_str()), "{e}");
        assert!(cut
            .admit(&json!({"partition": layout}), &Facts::default())
            .is_ok());
        assert!(kind("nope").unwrap_err().message.contains("compensate"));
    }

    /// What a kind needs of the machine is what the service resolves for it.
    #[test]
    fn a_kind_says_what_it_uses() {
        let uses = |name: &str| find(name).unwrap().uses;
        assert!(uses("compensate").devices);
        assert_eq!(uses("verify").map, MapUse::Always);
        assert_eq!(uses("iso230").map, MapUse::WhenAsked);
        assert!(uses("rotary").rotary && !uses("rotary").devices);
        let iso = find("iso230").unwrap();
        assert!(!iso.uses_map(&json!({"axis": "x"})));
        assert!(iso.uses_map(&json!({"axis": "x", "with_map": true})));
        assert!(find("reference").unwrap().uses_map(&json!({})));
        // The pass-through opens the controller's port itself; with a rotary table's
        // errors it applies no map.
        let proxy = find("proxy").unwrap();
        assert!(proxy.uses.link && !uses("compensate").link);
        assert!(proxy.uses_map(&json!({})));
        let rotary = json!({"rotary": "{}", "controller": "/dev/ttyACM0"});
        assert!(!proxy.uses_map(&rotary));
    }
}
