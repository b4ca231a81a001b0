//! `cargo xtask`: developer workflows that are code rather than shell (matklad's cargo-xtask).
//!
//! Tasks: `lint` (the formatting and clippy gates of `.ci/run`). `bench` arrives with the
//! measurement issue.

use std::process::Command;

use anyhow::{Context, bail};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("lint") => lint(),
        Some(other) => bail!("unknown task `{other}`; tasks: lint"),
        None => {
            println!(
                "cargo xtask <task>\n\ntasks:\n  lint   cargo fmt --check and clippy with warnings denied"
            );
            Ok(())
        }
    }
}

fn lint() -> anyhow::Result<()> {
    run("cargo", &["fmt", "--all", "--", "--check"])?;
    run("cargo", &["clippy", "--workspace", "--all-targets", "--", "-D", "warnings"])
}

fn run(program: &str, args: &[&str]) -> anyhow::Result<()> {
    let status = Command::new(program)
        .args(args)
        .status()
        .with_context(|| format!("could not start {program}"))?;
    if !status.success() {
        bail!("{program} {} failed with {status}", args.join(" "));
    }
    Ok(())
}
