//! The documentation against the command line: the flag reference (`docs/flags.md`) lists
//! exactly the flags `spsr <command> --help` shows, its table of PoissonRecon spellings lists
//! exactly the hidden ones, and every flag the README and the docs use exists.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use clap::CommandFactory;

const COMMANDS: [&str; 5] = ["reconstruct", "trim", "eval", "normals", "render"];

/// Flags every command has, documented once at the top of `docs/flags.md`.
const EVERYWHERE: [&str; 2] = ["--help", "--version"];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn read(relative: &str) -> String {
    let path = root().join(relative);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `command` as clap builds it for `spsr <command> --help`.
fn command(name: &str) -> clap::Command {
    let mut cli = spsr_cli::Cli::command();
    cli.build();
    cli.find_subcommand(name)
        .unwrap_or_else(|| panic!("no command {name}"))
        .clone()
}

/// The long flags `spsr <command> --help` prints: the options' lines of the long help.
fn shown_flags(name: &str) -> BTreeSet<String> {
    let help = command(name).render_long_help().to_string();
    help.lines()
        .filter_map(|line| {
            let t = line.trim_start();
            // `-o, --output <OUTPUT>` or `--depth <D>`, indented; prose never starts so.
            let t = t
                .strip_prefix('-')
                .and_then(|r| r.split_once(", "))
                .map_or(t, |(short, rest)| if short.len() == 1 { rest } else { t });
            (line.starts_with("  ") && t.starts_with("--")).then(|| flag_at(t))
        })
        .collect()
}

/// The long flags clap accepts but `--help` does not show: hidden arguments and aliases.
fn hidden_flags(name: &str) -> BTreeSet<String> {
    let cmd = command(name);
    let mut hidden = BTreeSet::new();
    for arg in cmd.get_arguments() {
        if let Some(long) = arg.get_long() {
            if arg.is_hide_set() {
                hidden.insert(format!("--{long}"));
            }
        }
        for alias in arg.get_aliases().unwrap_or_default() {
            hidden.insert(format!("--{alias}"));
        }
    }
    hidden
}

/// Every long flag `name` accepts, shown or hidden.
fn accepted_flags(name: &str) -> BTreeSet<String> {
    let mut all = shown_flags(name);
    all.extend(hidden_flags(name));
    all
}

/// The flag that `text` starts with (`--name`, up to the first character that cannot be
/// in a flag's name).
fn flag_at(text: &str) -> String {
    let name: String = text[2..]
        .chars()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
        .collect();
    format!("--{name}")
}

/// The long flags in `text`: every `--name` not preceded by a letter, digit or `-`.
fn flags_in(text: &str) -> Vec<String> {
    let bytes = text.as_bytes();
    text.match_indices("--")
        .filter(|&(i, _)| {
            let before_ok =
                i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'-');
            let after_ok = bytes.get(i + 2).is_some_and(|c| c.is_ascii_alphabetic());
            before_ok && after_ok
        })
        .map(|(i, _)| flag_at(&text[i..]))
        .collect()
}

/// The sections of a Markdown file by their `## ` heading, each with its lines.
fn sections(text: &str) -> Vec<(String, Vec<&str>)> {
    let mut out: Vec<(String, Vec<&str>)> = Vec::new();
    for line in text.lines() {
        if let Some(title) = line.strip_prefix("## ") {
            out.push((title.trim().to_string(), Vec::new()));
        } else if let Some((_, lines)) = out.last_mut() {
            lines.push(line);
        }
    }
    out
}

/// The flags in the first column of a section's table (rows after the header and its
/// separator; the first cell is one code span such as `` `-o, --output <OUTPUT>` ``).
fn table_flags(lines: &[&str]) -> BTreeSet<String> {
    lines
        .iter()
        .filter(|l| l.starts_with("| `"))
        .filter_map(|l| l[3..].split_once("` |").map(|(cell, _)| cell))
        .flat_map(flags_in)
        .collect()
}

#[test]
fn the_flag_reference_lists_exactly_what_help_shows() {
    let doc = read("docs/flags.md");
    let sections = sections(&doc);
    for name in COMMANDS {
        let title = format!("spsr {name}");
        let (_, lines) = sections
            .iter()
            .find(|(t, _)| *t == title)
            .unwrap_or_else(|| panic!("docs/flags.md has no section '## {title}'"));
        let documented = table_flags(lines);
        let mut shown = shown_flags(name);
        assert!(shown.len() >= 3, "{name}: too few flags read from --help");
        for f in EVERYWHERE {
            assert!(shown.remove(f), "{name} --help does not show {f}");
        }
        let missing: Vec<_> = shown.difference(&documented).collect();
        let extra: Vec<_> = documented.difference(&shown).collect();
        assert!(
            missing.is_empty(),
            "spsr {name} --help shows flags docs/flags.md does not list: {missing:?}"
        );
        assert!(
            extra.is_empty(),
            "docs/flags.md lists flags spsr {name} --help does not show: {extra:?}"
        );
    }
    for f in EVERYWHERE {
        assert!(doc.contains(&format!("`{f}`")) || doc.contains(&format!(", {f}`")));
    }
}

#[test]
fn the_poissonrecon_spellings_are_exactly_the_hidden_flags() {
    let doc = read("docs/flags.md");
    let (_, lines) = sections(&doc)
        .into_iter()
        .find(|(t, _)| t == "PoissonRecon spellings")
        .expect("docs/flags.md has a section '## PoissonRecon spellings'");
    // Only the first column: the second names spsr's own flags.
    let documented = table_flags(&lines);
    let hidden = hidden_flags("reconstruct");
    assert!(hidden.contains("--samplesPerNode"), "{hidden:?}");
    assert_eq!(documented, hidden);
    for name in COMMANDS.iter().filter(|&&n| n != "reconstruct") {
        assert_eq!(hidden_flags(name), BTreeSet::new(), "{name}");
    }
}

/// Every `spsr <command> ...` line in a code block of `file` uses only flags of that command.
fn check_command_lines(file: &str, text: &str) -> usize {
    let mut checked = 0;
    let mut in_code = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
            continue;
        }
        if !in_code {
            continue;
        }
        // A line may pipe several commands; a comment ends the command.
        let code = line.split(" #").next().unwrap_or(line);
        for part in code.split('|') {
            let words: Vec<&str> = part.split_whitespace().collect();
            // `python -m spsr.distributed` takes reconstruct's flags and two of its own.
            let (name, args, own): (&str, usize, &[&str]) =
                match words.iter().position(|w| *w == "spsr.distributed") {
                    Some(at) => ("reconstruct", at + 1, &["--scheduler", "--workers"]),
                    None => {
                        let Some(at) = words.iter().position(|w| *w == "spsr") else {
                            continue;
                        };
                        let Some(&name) = words.get(at + 1) else {
                            continue;
                        };
                        (name, at + 2, &[])
                    }
                };
            if !COMMANDS.contains(&name) {
                continue;
            }
            let accepted = accepted_flags(name);
            for flag in flags_in(&words[args..].join(" ")) {
                assert!(
                    accepted.contains(&flag)
                        || EVERYWHERE.contains(&flag.as_str())
                        || own.contains(&flag.as_str()),
                    "{file}: `{}` uses {flag}, which spsr {name} does not have",
                    line.trim()
                );
                checked += 1;
            }
        }
    }
    checked
}

#[test]
fn the_command_lines_in_the_readme_and_the_docs_run() {
    let mut checked = 0;
    let mut files = vec!["README.md".to_string()];
    for entry in std::fs::read_dir(root().join("docs")).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        if name.ends_with(".md") {
            files.push(format!("docs/{name}"));
        }
    }
    for file in &files {
        checked += check_command_lines(file, &read(file));
    }
    assert!(checked > 20, "only {checked} flags found in command lines");
}

#[test]
fn every_flag_the_readme_names_exists() {
    let readme = read("README.md");
    let mut all = BTreeSet::new();
    for name in COMMANDS {
        all.extend(accepted_flags(name));
    }
    // Inline code spans that start with a flag: `--depth 9`, `--trim auto`.
    let spans = readme.split('`').skip(1).step_by(2);
    let mut named = 0;
    for span in spans.filter(|s| s.starts_with("--")) {
        let flag = flag_at(span);
        assert!(
            all.contains(&flag) || EVERYWHERE.contains(&flag.as_str()),
            "README.md names {flag}, which no spsr command has"
        );
        named += 1;
    }
    assert!(named >= 5, "only {named} flags named in README.md");
}

#[test]
fn the_flag_finder_reads_flags_and_nothing_else() {
    assert_eq!(
        flags_in("`-o, --output <OUT>` x--y --noise <adaptive\\|off> -- --2 ---"),
        vec!["--output", "--noise"]
    );
    assert_eq!(
        table_flags(&[
            "| Flag | Default |",
            "|---|---|",
            "| `--size <WxH>` | 800x800 |"
        ]),
        BTreeSet::from(["--size".to_string()])
    );
}
