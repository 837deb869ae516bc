//! The command line as a user meets it: every subcommand's `--help` ends with examples, `--version`
//! names the commit the binary was built from, the shell completions are valid shell, and the
//! manual pages are roff, one per subcommand, and every summary ends with a newline.

use crate::common::*;
use std::process::Command;

fn stdout_of(args: &[&str]) -> String {
    let o = run(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

/// The subcommands, as `bimtiles --help` lists them (clap's own `help` aside).
fn subcommands() -> Vec<String> {
    let help = stdout_of(&["--help"]);
    let listed = help.split("Commands:").nth(1).expect("a Commands section");
    let names: Vec<String> = listed
        .lines()
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .filter(|n| n != "help")
        .collect();
    assert!(names.len() >= 8, "{names:?}");
    names
}

#[test]
fn every_subcommand_help_ends_with_examples() {
    for sub in subcommands() {
        let help = stdout_of(&[&sub, "--help"]);
        let examples = help
            .split("Examples:\n")
            .nth(1)
            .unwrap_or_else(|| panic!("{sub} --help has no examples:\n{help}"));
        let lines: Vec<&str> = examples.lines().filter(|l| !l.trim().is_empty()).collect();
        assert!(
            (2..=3).contains(&lines.len()),
            "{sub}: {} example lines",
            lines.len()
        );
        for l in lines {
            assert!(
                l.trim_start().starts_with("bimtiles ") || l.trim_start().starts_with("for "),
                "{sub}: {l}"
            );
        }
    }
}

#[test]
fn version_names_the_commit() {
    let version = stdout_of(&["--version"]);
    let prefix = format!("bimtiles {} (", env!("CARGO_PKG_VERSION"));
    let commit = version
        .trim()
        .strip_prefix(&prefix)
        .and_then(|rest| rest.strip_suffix(')'))
        .unwrap_or_else(|| panic!("--version printed {version:?}"));
    let git = |args: &[&str]| {
        Command::new("git")
            .args(args)
            .current_dir(repo())
            .output()
            .ok()
            .filter(|o| o.status.success())
    };
    if git(&["rev-parse", "--git-dir"]).is_none() {
        // Built outside a git checkout (a crate tarball): nothing to name.
        assert_eq!(commit, "unknown");
        return;
    }
    // A commit of this repository, by its short hash (HEAD may have moved since the build).
    assert_eq!(commit.len(), 12, "{commit}");
    assert!(
        git(&["cat-file", "-e", &format!("{commit}^{{commit}}")]).is_some(),
        "{commit} is no commit of this repository"
    );
}

#[test]
fn completions_are_valid_shell() {
    let dir = tmpdir("cli-completions");
    let script = dir.join("bimtiles.bash");
    std::fs::write(&script, stdout_of(&["completions", "bash"])).unwrap();
    let check = Command::new("bash")
        .arg("-n")
        .arg(&script)
        .output()
        .unwrap();
    assert!(
        check.status.success(),
        "{}",
        String::from_utf8_lossy(&check.stderr)
    );
    // The script completes the subcommands and their options.
    let text = std::fs::read_to_string(&script).unwrap();
    for word in [
        "convert",
        "build-job",
        "--max-tile-triangles",
        "--strict-georef",
    ] {
        assert!(text.contains(word), "no {word} in the bash completions");
    }
    for shell in ["zsh", "fish"] {
        assert!(
            stdout_of(&["completions", shell]).contains("convert"),
            "{shell}"
        );
    }
    let o = run(&["completions", "no-such-shell"]);
    assert_eq!(o.status.code(), Some(2), "clap's usage error");
}

#[test]
fn man_pages_cover_every_subcommand() {
    let top = stdout_of(&["man"]);
    assert!(top.contains(".TH bimtiles 1"), "{top}");
    let dir = tmpdir("cli-man");
    stdout_of(&["man", "--out-dir", dir.to_str().unwrap()]);
    for sub in subcommands() {
        let page = std::fs::read_to_string(dir.join(format!("bimtiles-{sub}.1")))
            .unwrap_or_else(|e| panic!("bimtiles-{sub}.1: {e}"));
        assert!(page.contains(&format!(".TH bimtiles-{sub} 1")), "{sub}");
        assert!(
            page.contains(".SH OPTIONS") || sub == "man",
            "{sub}: {page}"
        );
    }
    let convert = std::fs::read_to_string(dir.join("bimtiles-convert.1")).unwrap();
    assert!(
        convert.contains("max\\-tile\\-triangles"),
        "convert's options are on its page"
    );
}

/// An element of the bundled sample (a column with an exact duplicate, `sample_building.expect.json`).
const KEPT_COLUMN: &str = "2ly2pe6nJWfJEs5ygkN$0U";

/// What `convert`, `simplify` and `inspect` print ends with a newline, so a shell prompt or the
/// next line of a script never lands on the summary's last line.
#[test]
fn every_summary_ends_with_a_newline() {
    let dir = tmpdir("cli-summary-newline");
    let out = dir.join("tiles");
    let (sample, out_s) = (sample(), out.to_str().unwrap());
    let converted = stdout_of(&["convert", sample.to_str().unwrap(), "--out", out_s]);
    let simplified = dir.join("simplified.glb");
    let summaries = [
        ("convert", converted),
        ("inspect", stdout_of(&["inspect", out_s])),
        ("inspect --json", stdout_of(&["inspect", out_s, "--json"])),
        (
            "simplify",
            stdout_of(&[
                "simplify",
                sample.to_str().unwrap(),
                "--ratio",
                "0.5",
                "--out",
                simplified.to_str().unwrap(),
            ]),
        ),
    ];
    let feature = (
        "inspect --feature",
        stdout_of(&["inspect", out_s, "--feature", KEPT_COLUMN]),
    );
    for (what, text) in summaries.into_iter().chain([feature]) {
        assert!(!text.is_empty(), "{what} printed nothing");
        assert!(
            text.ends_with('\n'),
            "{what} does not end with a newline: {text:?}"
        );
    }
}
