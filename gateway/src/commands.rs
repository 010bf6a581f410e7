//! Every registered kind as a command, built from the registry alone: its words
//! (`rotary identify`), its request's flags and its file arguments
//! ([`procedure::command_line`]). Running one reads the files the kind declares into its
//! request, runs it in the files context with Ctrl-C as the stop signal, and prints the
//! outcome with the kind's summary and what was written where.

use crate::front::{print, run_outcome, CliSink};
use clap::{Arg, ArgAction, ArgMatches, Command};
use procedure::command_line::{FileArg, Plan};
use procedure::registry::Kind;
use procedure::KINDS;
use serde_json::Value;
use std::path::PathBuf;
use std::process::ExitCode;

/// `root` with every registered kind's command added under its words.
pub fn add_kinds(mut root: Command) -> Command {
    for kind in KINDS {
        let words: Vec<&str> = kind.command.split(' ').collect();
        root = add_at(root, &words, kind);
    }
    root
}

fn add_at(mut parent: Command, words: &[&'static str], kind: &'static Kind) -> Command {
    let (word, rest) = words.split_first().expect("a command has words");
    if parent.find_subcommand(word).is_none() {
        let about = GROUPS.iter().find(|(w, _)| w == word).map(|(_, a)| *a);
        parent = parent.subcommand(Command::new(*word).about(about));
    }
    parent.mut_subcommand(*word, |node| {
        if rest.is_empty() {
            return leaf(node, kind);
        }
        // A group (`rotary`) needs one of its commands; a kind that is also a group
        // (`iso230` and `iso230 evaluate`) takes its own flags or the subcommand.
        let node = add_at(node, rest, kind);
        if node.get_arguments().next().is_some() {
            node.args_conflicts_with_subcommands(true)
                .subcommand_negates_reqs(true)
        } else {
            node.subcommand_required(true)
        }
    })
}

/// The words that group several kinds, and what they are about.
const GROUPS: &[(&str, &str)] = &[
    (
        "layout",
        "Cutting layouts for a multi-tool conveyor cutter (source C)",
    ),
    (
        "rotary",
        "The A/C tilting rotary table (source B): its eight location errors",
    ),
    (
        "volumetric",
        "The 21-error volumetric model of a 3-axis machine (source D)",
    ),
    ("board", "Calibration boards"),
];

fn leaf(node: Command, kind: &'static Kind) -> Command {
    // The request's own documentation speaks to developers; the command says what it does.
    let mut node = kind.flags(node).about(kind.title).long_about(None);
    for file in kind.files {
        node = node.arg(file_arg(file));
    }
    if node.get_subcommands().next().is_some() {
        node = node
            .args_conflicts_with_subcommands(true)
            .subcommand_negates_reqs(true);
    }
    node
}

fn file_arg(file: &FileArg) -> Arg {
    let mut arg = Arg::new(file.name)
        .help(file.help)
        .value_name(file.value_name)
        .value_parser(clap::value_parser!(PathBuf))
        .action(ArgAction::Set)
        .required(file.required);
    if !file.positional {
        arg = arg.long(file.name);
    }
    if let Some(letter) = file.short {
        arg = arg.short(letter);
    }
    for id in file.requires {
        arg = arg.requires(*id);
    }
    if !file.conflicts.is_empty() {
        arg = arg.conflicts_with_all(file.conflicts);
    }
    if !file.required_unless.is_empty() {
        arg = arg.required_unless_present_any(file.required_unless);
    }
    arg
}

/// The registered kind the matches name, with the matches of its own command.
pub fn matched(matches: &ArgMatches) -> Option<(&'static Kind, &ArgMatches)> {
    let mut words = Vec::new();
    let mut at = matches;
    while let Some((word, sub)) = at.subcommand() {
        words.push(word);
        at = sub;
    }
    let command = words.join(" ");
    let kind = KINDS.iter().find(|k| k.command == command)?;
    Some((kind, at))
}

/// Runs the kind the command line named.
pub fn run(kind: &'static Kind, matches: &ArgMatches, json: bool) -> anyhow::Result<ExitCode> {
    let mut params = kind.from_flags(matches)?;
    let mut plan = Plan::default();
    for file in kind.files {
        if let Some(path) = matches.get_one::<PathBuf>(file.name) {
            (file.apply)(path, &mut plan).map_err(anyhow::Error::msg)?;
        }
    }
    plan.apply_to(&mut params);
    let mut sink = CliSink::new(kind.steps, json || kind.steps.is_empty())
        .inputs(&plan.read_files())
        .print_partials(json, kind);
    if let Some(dir) = &plan.folder {
        sink = sink.into_folder(dir);
    }
    for (name, path) in &plan.artifacts {
        sink = sink.artifact_to(name, path.clone());
    }
    let mut outcome = run_outcome(kind, &params, &mut sink, |mut f| {
        if let Some(path) = &plan.job {
            f = f.job_file(path);
        }
        if let Some(path) = &plan.map {
            f = f.map_file(path);
        }
        if let Some(path) = &plan.rotary {
            f = f.rotary_file(path);
        }
        if let Some(path) = &plan.board {
            f = f.board_file(path);
        }
        for input in &plan.inputs {
            f = f.input(input);
        }
        match (&plan.folder, plan.folder_for_artifacts_only) {
            (Some(dir), false) => f.out_folder(dir),
            _ => f,
        }
    })?;
    let written = sink.written();
    if let Some(result) = outcome.result.as_mut() {
        name_written_files(result, &written);
    }
    let code = print(&outcome, json, |r| {
        let mut text = kind.summary(r);
        let mut paths: Vec<String> = written
            .iter()
            .map(|(_, p)| p.display().to_string())
            .collect();
        paths.dedup();
        if !paths.is_empty() {
            if !text.ends_with('\n') && !text.is_empty() {
                text.push('\n');
            }
            text += &format!("written: {}", paths.join(", "));
        }
        text
    })?;
    let verdict = outcome.result.as_ref().map_or(0, |r| kind.exit_code(r));
    Ok(if code == ExitCode::SUCCESS && verdict != 0 {
        ExitCode::from(verdict)
    } else {
        code
    })
}

/// The result's `file` and `output` fields (an artifact's name) become the path it was
/// written to, and a run that wrote one file of its own names it as `output`.
fn name_written_files(result: &mut Value, written: &[(String, PathBuf)]) {
    fn walk(v: &mut Value, written: &[(String, PathBuf)]) {
        match v {
            Value::Object(o) => {
                for key in ["file", "output"] {
                    let Some(Value::String(name)) = o.get(key) else {
                        continue;
                    };
                    if let Some((_, path)) = written.iter().find(|(n, _)| n == name) {
                        o.insert(key.into(), path.display().to_string().into());
                    }
                }
                o.values_mut().for_each(|v| walk(v, written));
            }
            Value::Array(a) => a.iter_mut().for_each(|v| walk(v, written)),
            _ => {}
        }
    }
    walk(result, written);
    if let ([(_, path)], Some(o)) = (written, result.as_object_mut()) {
        o.entry("output")
            .or_insert_with(|| path.display().to_string().into());
    }
}
