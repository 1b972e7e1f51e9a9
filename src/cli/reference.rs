//! The CLI reference (docs/reference/cli.md), generated from clap's own help for every command and subcommand, so
//! that it cannot drift from the binary: a test compares the file with [`markdown`] and fails when it is stale
//! (`make cli-reference` writes it again).

use clap::CommandFactory;

/// The repository path of the generated reference.
pub const PATH: &str = "docs/reference/cli.md";

fn walk(cmd: &mut clap::Command, path: &str, out: &mut String) {
    let name = if path.is_empty() { cmd.get_name().to_string() } else { format!("{path} {}", cmd.get_name()) };
    let help = cmd.render_long_help().to_string();
    let depth = name.split(' ').count().min(4);
    out.push_str(&format!("{} `{name}`\n\n```text\n{}\n```\n\n", "#".repeat(depth + 1), help.trim_end()));
    let mut subs: Vec<clap::Command> = cmd.get_subcommands().filter(|s| s.get_name() != "help").cloned().collect();
    for s in &mut subs {
        walk(s, &name, out);
    }
}

/// The whole reference as Markdown: each command's `--help` in the order `msnerf --help` lists them.
pub fn markdown() -> String {
    let mut cmd = super::Cli::command().bin_name("msnerf");
    cmd.build();
    let mut out = String::from(
        "# msnerf command-line reference\n\nGenerated from the binary's own `--help` (`make cli-reference`; a test \
         fails when this file is stale). Every command also prints this with `--help`.\n\n",
    );
    walk(&mut cmd, "", &mut out);
    out
}

#[cfg(test)]
mod tests {
    /// The checked-in reference is the binary's help; set `MSNERF_UPDATE_REFERENCE=1` to write it.
    #[test]
    fn cli_reference_is_current() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(super::PATH);
        let want = super::markdown();
        if std::env::var_os("MSNERF_UPDATE_REFERENCE").is_some() {
            crate::util::atomic::write_bytes(&path, want.as_bytes()).unwrap();
        }
        let have = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(have == want, "{} is stale: run `make cli-reference` and commit it", super::PATH);
        // Help texts speak to users: no internal issue numbers.
        let lower = want.to_lowercase();
        let cites = lower
            .match_indices("issue ")
            .filter(|(i, _)| lower[i + 6..].chars().next().is_some_and(|c| c.is_ascii_digit()));
        assert_eq!(cites.count(), 0, "the help cites internal issue numbers");
    }
}
