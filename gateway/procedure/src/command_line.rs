//! What a procedure's files are on the command line: each kind declares its file
//! arguments ([`FileArg`]) once, and the `gateway` binary builds the command's flags and
//! runs it from them alone. A file argument's [`Apply`] reads the file through the bounded
//! reader into the request (the service has the same text from an upload or its store)
//! or names it for the files context (job, map, rotary job, board, output folder, an
//! artifact's path): the rules of a capability's files live here, in the procedure, and
//! the binary only parses flags and prints.

use crate::Error;
use serde_json::{Map, Value};
use std::path::{Path, PathBuf};

/// What the command line's files make of a run: request fields read from files, and
/// the files context's paths. Filled by each given [`FileArg`] in declaration order.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Plan {
    /// Request fields set from files: `("program", text)`, nested as `partition/layout`.
    pub fields: Vec<(String, Value)>,
    /// The job file (`--config`).
    pub job: Option<PathBuf>,
    /// The error map.
    pub map: Option<PathBuf>,
    /// The rotary job file.
    pub rotary: Option<PathBuf>,
    /// The board file.
    pub board: Option<PathBuf>,
    /// Every other file read: never written over.
    pub inputs: Vec<PathBuf>,
    /// The output folder: artifacts not named in `artifacts`, journals, map versions.
    pub folder: Option<PathBuf>,
    /// Artifacts written to a path of their own: `(artifact name, path)`.
    pub artifacts: Vec<(String, PathBuf)>,
    /// Artifacts go into the folder but the files context has no output folder (no
    /// journal or map shelf): a folder of plots, a picture beside a file.
    pub folder_for_artifacts_only: bool,
}

impl Plan {
    /// Sets the request field at `path` (`a/b` for a field of a nested request).
    pub fn set(&mut self, path: &str, value: impl serde::Serialize) {
        let value = serde_json::to_value(value).expect("a request field is plain data");
        self.fields.push((path.to_string(), value));
    }

    /// The file's text read by `read` into `field`, and its name (as given) into
    /// `name_field`.
    pub fn text(
        &mut self,
        path: &Path,
        field: &str,
        name_field: Option<&str>,
        read: fn(&Path) -> Result<String, Error>,
    ) -> Result<(), Error> {
        self.set(field, read(path)?);
        if let Some(name) = name_field {
            self.set(name, path.display().to_string());
        }
        self.inputs.push(path.to_path_buf());
        Ok(())
    }

    /// The request `params` with every field of the plan set in it.
    pub fn apply_to(&self, params: &mut Value) {
        for (path, value) in &self.fields {
            let mut at = &mut *params;
            let mut words = path.split('/').peekable();
            while let Some(word) = words.next() {
                if !at.is_object() {
                    *at = Value::Object(Map::new());
                }
                let object = at.as_object_mut().expect("an object");
                if words.peek().is_none() {
                    object.insert(word.to_string(), value.clone());
                    break;
                }
                at = object
                    .entry(word)
                    .or_insert_with(|| Value::Object(Map::new()));
            }
        }
    }

    /// Every file the run reads (never written over).
    pub fn read_files(&self) -> Vec<&Path> {
        [&self.job, &self.map, &self.rotary, &self.board]
            .into_iter()
            .flatten()
            .chain(&self.inputs)
            .map(PathBuf::as_path)
            .collect()
    }
}

/// What a given file does to the plan.
pub type Apply = fn(&Path, &mut Plan) -> Result<(), Error>;

/// One file argument of a kind's command.
#[derive(Debug, Clone, Copy)]
pub struct FileArg {
    /// The flag's long name (`map` for `--map`), or a positional's value name (`input`).
    pub name: &'static str,
    pub positional: bool,
    /// A one-letter flag too (`-o`).
    pub short: Option<char>,
    /// What the help calls its value (`PATH`; a map's `NAME`).
    pub value_name: &'static str,
    pub required: bool,
    /// The command's help for it.
    pub help: &'static str,
    /// Arguments (flags' ids, `_` for `-`) it needs, or that it excludes.
    pub requires: &'static [&'static str],
    pub conflicts: &'static [&'static str],
    /// Required unless one of these is given.
    pub required_unless: &'static [&'static str],
    pub apply: Apply,
}

impl FileArg {
    /// An optional `--NAME FILE`.
    pub const fn flag(name: &'static str, help: &'static str, apply: Apply) -> Self {
        Self {
            name,
            positional: false,
            short: None,
            value_name: "PATH",
            required: false,
            help,
            requires: &[],
            conflicts: &[],
            required_unless: &[],
            apply,
        }
    }

    /// A required `--NAME FILE`.
    pub const fn required(name: &'static str, help: &'static str, apply: Apply) -> Self {
        Self {
            required: true,
            ..Self::flag(name, help, apply)
        }
    }

    /// A required positional FILE.
    pub const fn positional(name: &'static str, help: &'static str, apply: Apply) -> Self {
        Self {
            positional: true,
            required: true,
            ..Self::flag(name, help, apply)
        }
    }

    pub const fn short(self, letter: char) -> Self {
        Self {
            short: Some(letter),
            ..self
        }
    }

    pub const fn value_name(self, name: &'static str) -> Self {
        Self {
            value_name: name,
            ..self
        }
    }

    pub const fn requires(self, ids: &'static [&'static str]) -> Self {
        Self {
            requires: ids,
            ..self
        }
    }

    pub const fn conflicts(self, ids: &'static [&'static str]) -> Self {
        Self {
            conflicts: ids,
            ..self
        }
    }

    pub const fn required_unless(self, ids: &'static [&'static str]) -> Self {
        Self {
            required: false,
            required_unless: ids,
            ..self
        }
    }
}

/// `--config JOB --map MAP`: the machine's job and the error map it checks.
pub const JOB_AND_MAP: &[FileArg] = &[
    FileArg::required("config", "The job file of the machine.", job),
    FileArg::required(
        "map",
        "The error map (a version file written by `gateway map`).",
        map,
    ),
];

/// The job file: the files context loads it (and opens its devices on first use).
pub fn job(path: &Path, plan: &mut Plan) -> Result<(), Error> {
    plan.job = Some(path.to_path_buf());
    Ok(())
}

/// The error map: a version file; its reference record is read beside it.
pub fn map(path: &Path, plan: &mut Plan) -> Result<(), Error> {
    plan.map = Some(path.to_path_buf());
    Ok(())
}

/// The rotary job file.
pub fn rotary_job(path: &Path, plan: &mut Plan) -> Result<(), Error> {
    plan.rotary = Some(path.to_path_buf());
    Ok(())
}

/// The board file.
pub fn board(path: &Path, plan: &mut Plan) -> Result<(), Error> {
    plan.board = Some(path.to_path_buf());
    Ok(())
}

/// The output folder: every artifact, the journal and the map versions go there.
pub fn out_folder(path: &Path, plan: &mut Plan) -> Result<(), Error> {
    plan.folder = Some(path.to_path_buf());
    Ok(())
}

/// A folder for the artifacts only (charts, plots).
pub fn artifacts_folder(path: &Path, plan: &mut Plan) -> Result<(), Error> {
    plan.folder = Some(path.to_path_buf());
    plan.folder_for_artifacts_only = true;
    Ok(())
}

/// The lower-case extension of a path (`""` when it has none).
pub fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn plan_fields_land_in_nested_requests() {
        let mut plan = Plan::default();
        plan.set("program", "G1 X1");
        plan.set("partition/layout", "{}");
        plan.set("partition/format", "json");
        let mut params = json!({"program": "", "partition": {"tools": 2}});
        plan.apply_to(&mut params);
        assert_eq!(
            params,
            json!({"program": "G1 X1", "partition": {"tools": 2, "layout": "{}", "format": "json"}})
        );
        let plan = Plan {
            job: Some("j.toml".into()),
            inputs: vec!["p.nc".into()],
            ..Plan::default()
        };
        assert_eq!(plan.read_files(), [Path::new("j.toml"), Path::new("p.nc")]);
    }
}
