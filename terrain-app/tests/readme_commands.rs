//! Every shell command of README.md runs as written: the test reads README.md's ```sh blocks
//! itself (so a command added later is covered without editing this file), runs each command in
//! order in a scratch copy of the repository's layout (`../shared/data` reachable as the README
//! says, `flights/` beside it), with `terrain` and `cargo run --release -p terrain-app --` meaning
//! the `terrain` binary cargo built for the tests, and fails on a non-zero exit naming the command
//! and its stderr. It checks what the commands write where that is cheap (a PNG decodes and is
//! not one flat colour, a store has its index, a folder is not empty, JSON parses) and that
//! nothing is written outside the git-ignored `out/` folder.
//!
//! Commands too slow for a debug build, or that cannot run here, are in [`ALLOW_LIST`] with the
//! reason: run with size-reducing options the README documents, or not run at all. An
//! allow-listed command that is no longer in the README (removed or changed) fails the test, so
//! the list cannot rot.

mod common;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// What the test does instead of running an allow-listed command as written.
#[derive(Debug, Clone, Copy)]
enum Treatment {
    /// Not run by this test; the reason says why and what runs it instead.
    NotRun(&'static str),
    /// Run reduced: this command instead (the README's command with size-reducing options it
    /// documents), for the reason given.
    Reduced { run: &'static str, why: &'static str },
}

/// A `terrain view` command run under `xvfb-run` (a display of its own; Vulkan, lavapipe
/// here, as in `view_cli.rs`).
macro_rules! under_xvfb {
    ($tail:literal) => {
        concat!(
            "TERRAIN_GPU_BACKEND=vulkan xvfb-run -a -s \"-screen 0 1280x800x24 -nolisten tcp\" ",
            $tail
        )
    };
}

/// Why the `terrain view` lines run reduced.
const VIEW_WHY: &str = "a window needs a display: run under xvfb-run (Vulkan: lavapipe here) at \
                        320x180 with the README's example script docs/view_script.txt, which \
                        moves, sets the quality slider, takes a screenshot and quits";

/// The README commands (exactly as [`sh_commands`] gives them: continuation lines joined,
/// comments and repeated blanks removed) that this test does not run as written, each with why.
const ALLOW_LIST: &[(&str, Treatment)] = &[
    (
        "cargo run --release -p terrain-app -- demo",
        Treatment::NotRun(
            "the same demo as `terrain demo` below, which runs here reduced (a release build \
             inside the test would rebuild the workspace)",
        ),
    ),
    (
        "terrain demo",
        Treatment::Reduced {
            run: "terrain demo --size 1025",
            why: "the 8193^2 demo is a release-build minute of CPU (see the README's top); \
                  `--size 1025` runs every step of it (generation, bake, flight, benchmark \
                  from the store, checked frames, report, plot) on a grid 64 times smaller",
        },
    ),
    (
        "cargo test --workspace",
        Treatment::NotRun(
            "this test is one of the workspace's tests (it would run itself); .ci/run runs it",
        ),
    ),
    (
        "cargo xtask bench --quick",
        Treatment::NotRun(
            "builds `terrain` in release and benchmarks every method on two DEMs: about 16 \
             minutes on two cores; `terrain bench ... --quick` below is the same code, reduced",
        ),
    ),
    (
        "cargo xtask bench",
        Treatment::NotRun(
            "the full benchmark (both backends, every flight): hours; the same code as \
             `terrain bench`, which runs here reduced",
        ),
    ),
    (
        "terrain render out/big.scene --flight flights/fast_pass.json --max-frames 60 --page-mib \
         256 -o out/last.png",
        Treatment::Reduced {
            run: "terrain render out/big.scene --flight flights/fast_pass.json --max-frames 4 \
                  --page-mib 256 --size 320x180 -o out/last.png",
            why: "each 1280x720 frame of about a million triangles takes seconds on lavapipe; \
                  4 frames at 320x180 run the same streamed flight (first frame waits, later \
                  frames stream) and write the last frame",
        },
    ),
    (
        "terrain fly out/ps1k.scene --flight flights/pvps_884.json --method dss-2 --frames 30 -o \
         out/fly-store/",
        Treatment::Reduced {
            run: "terrain fly out/ps1k.scene --flight flights/pvps_884.json --method dss-2 \
                  --frames 4 --size 320x180 -o out/fly-store/",
            why: "30 frames are as many passes of the same frame loop; 4 small ones write the \
                  same files",
        },
    ),
    (
        "terrain fly --flight flights/pvps_884.json --frames 90 -o out/fly/",
        Treatment::Reduced {
            run: "terrain fly --flight flights/pvps_884.json --frames 6 -o out/fly/",
            why: "90 frames are as many passes of the same frame loop; 6 write the same files",
        },
    ),
    (
        "terrain bench ../shared/data/srtm/N42E001.hgt --flight flights/pvps_884.json --methods \
         pvps-c,pvps-c-pvs,pvps-c-cons --scene out/n42-pvs.scene --no-render",
        Treatment::Reduced {
            run: "terrain bench ../shared/data/srtm/N42E001.hgt --flight flights/pvps_884.json \
                  --methods pvps-c,pvps-c-pvs,pvps-c-cons --scene out/n42-pvs.scene --no-render \
                  --frames 3 --sweep 2",
            why: "60 frames x 5 sweep points of exact error measurement; 3 frames x 2 points \
                  run the same code and write the same report",
        },
    ),
    (
        "terrain bench ../shared/data/puget_sound/ps_height_1k.png --vertical-scale 0.1 \
         --spacing 160 --flight flights/pvps_884.json --flight flights/dss_approach.json --quick \
         -o out/bench",
        Treatment::Reduced {
            run: "terrain bench ../shared/data/puget_sound/ps_height_1k.png --vertical-scale 0.1 \
                  --spacing 160 --flight flights/pvps_884.json --flight \
                  flights/dss_approach.json --quick -o out/bench \
                  --methods uniform,pvps-c,dss-2,geomorph --frames 2 --sweep 2",
            why: "--quick still measures twelve methods x 3 sweep points x 20 frames x 2 flights, \
                  several minutes in a debug build; four methods, 2 points and 2 frames each run \
                  every stage (render, CPU surface, exact error) and write the same report files",
        },
    ),
    (
        "terrain view ../shared/data/puget_sound/ps_height_1k.png --vertical-scale 0.1 --spacing \
         160",
        Treatment::Reduced {
            run: under_xvfb!(
                "terrain view ../shared/data/puget_sound/ps_height_1k.png \
                --vertical-scale 0.1 --spacing 160 --size 320x180 --script \
                docs/view_script.txt"
            ),
            why: VIEW_WHY,
        },
    ),
    (
        "terrain view out/ps1k.scene",
        Treatment::Reduced {
            run: under_xvfb!(
                "terrain view out/ps1k.scene --size 320x180 --script \
                docs/view_script.txt"
            ),
            why: VIEW_WHY,
        },
    ),
    (
        "terrain view --method dss-1 --error-px 1 --size 1600x900",
        Treatment::Reduced {
            run: under_xvfb!(
                "terrain view --method dss-1 --error-px 1 --size 320x180 --script \
                docs/view_script.txt"
            ),
            why: VIEW_WHY,
        },
    ),
    (
        "terrain view --method geomorph --quality fast",
        Treatment::Reduced {
            run: under_xvfb!(
                "terrain view --method geomorph --quality fast --size 320x180 --script \
                docs/view_script.txt"
            ),
            why: VIEW_WHY,
        },
    ),
    (
        "terrain view ../shared/data/puget_sound/ps_height_1k.png --vertical-scale 0.1 --spacing \
         160 --flight flights/valley_low.json",
        Treatment::Reduced {
            run: under_xvfb!(
                "terrain view ../shared/data/puget_sound/ps_height_1k.png \
                --vertical-scale 0.1 --spacing 160 --flight flights/valley_low.json \
                --size 320x180 --script docs/view_script.txt"
            ),
            why: VIEW_WHY,
        },
    ),
    (
        "terrain view --script docs/view_script.txt",
        Treatment::Reduced {
            run: under_xvfb!("terrain view --script docs/view_script.txt --size 320x180"),
            why: VIEW_WHY,
        },
    ),
];

/// The longest any one command may take before the test fails (a hang, not a slow command).
const COMMAND_TIMEOUT: Duration = Duration::from_secs(600);

/// One command of the README's ```sh blocks.
#[derive(Debug, Clone, PartialEq)]
struct ReadmeCommand {
    /// 1-based line of README.md where the command starts.
    line: usize,
    /// The command: continuation lines joined, comment removed, blanks collapsed.
    text: String,
}

/// The commands of every ```sh (or ```bash, ```shell) block of `readme`, in order.
fn sh_commands(readme: &str) -> Vec<ReadmeCommand> {
    let mut out = Vec::new();
    let mut in_block = false;
    let mut pending: Option<(usize, String)> = None;
    for (i, raw) in readme.lines().enumerate() {
        let line = raw.trim_end();
        let fence = line.trim_start();
        if !in_block {
            in_block = matches!(fence, "```sh" | "```bash" | "```shell");
            continue;
        }
        if fence.starts_with("```") {
            assert!(pending.is_none(), "README.md line {}: a `\\` continues into the fence", i + 1);
            in_block = false;
            continue;
        }
        let (start, mut acc) = pending.take().unwrap_or((i + 1, String::new()));
        let code = strip_comment(line);
        if let Some(head) = code.trim_end().strip_suffix('\\') {
            acc.push_str(head);
            acc.push(' ');
            pending = Some((start, acc));
            continue;
        }
        acc.push_str(&code);
        let text = acc.split_whitespace().collect::<Vec<_>>().join(" ");
        if !text.is_empty() {
            out.push(ReadmeCommand { line: start, text });
        }
    }
    assert!(!in_block, "README.md ends inside a ```sh block");
    out
}

/// `line` without its shell comment: a `#` that starts a word outside quotes.
fn strip_comment(line: &str) -> String {
    let mut quote = None;
    let mut prev_blank = true;
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (None, '\'' | '"') => quote = Some(c),
            (Some(q), _) if c == q => quote = None,
            (None, '#') if prev_blank => return line[..i].to_string(),
            _ => {}
        }
        prev_blank = c.is_whitespace();
    }
    line.to_string()
}

/// The command as the test runs it: `cargo run --release -p terrain-app --` is `terrain`.
fn as_run(text: &str) -> String {
    const CARGO_RUN: &str = "cargo run --release -p terrain-app -- ";
    match text.strip_prefix(CARGO_RUN) {
        Some(rest) => format!("terrain {rest}"),
        None => text.to_string(),
    }
}

fn treatment(text: &str) -> Option<Treatment> {
    ALLOW_LIST.iter().find(|(c, _)| *c == text).map(|&(_, t)| t)
}

/// Every file and folder under `root`, relative to it (symbolic links not followed).
fn tree(root: &Path) -> BTreeSet<PathBuf> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeSet<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap().map(Result::unwrap) {
            let p = e.path();
            out.insert(p.strip_prefix(root).unwrap().to_path_buf());
            if e.file_type().unwrap().is_dir() {
                walk(root, &p, out);
            }
        }
    }
    let mut out = BTreeSet::new();
    walk(root, root, &mut out);
    out
}

/// Copies the folder `from` to `to` (plain files only: the shipped flights).
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().map(Result::unwrap) {
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// Checks an image a command wrote: it decodes, and unless it is tiny (under 16 x 16 pixels: a
/// pyramid's top level) it is not a single flat colour.
fn check_image(cmd: &str, path: &Path) {
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("`{cmd}` wrote {} that does not decode: {e}", path.display()))
        .to_rgba8();
    assert!(img.width() > 0 && img.height() > 0, "`{cmd}`: {} is empty", path.display());
    if img.width() * img.height() < 256 {
        return;
    }
    let first = img.get_pixel(0, 0);
    assert!(
        img.pixels().any(|p| p != first),
        "`{cmd}`: {} is one flat colour {:?} (nothing drawn)",
        path.display(),
        first.0
    );
}

/// Checks a file or folder a command wrote, by its kind; returns how many files it looked at.
fn check_output(cmd: &str, path: &Path) -> usize {
    let meta = std::fs::metadata(path)
        .unwrap_or_else(|e| panic!("`{cmd}` did not write {}: {e}", path.display()));
    if meta.is_dir() {
        if path.join("index.tsi").exists() {
            // A baked store: the index and at least one block file.
            let blocks = path.join("blocks");
            assert!(
                std::fs::read_dir(&blocks).map(|d| d.count()).unwrap_or(0) > 0,
                "`{cmd}`: the store {} has no blocks",
                path.display()
            );
            return 1;
        }
        let mut checked = 0;
        let mut entries: Vec<_> =
            std::fs::read_dir(path).unwrap().map(|e| e.unwrap().path()).collect();
        entries.sort();
        assert!(!entries.is_empty(), "`{cmd}` wrote an empty folder {}", path.display());
        for p in entries.iter().filter(|p| p.is_file()).take(8) {
            checked += check_output(cmd, p);
        }
        return checked;
    }
    assert!(meta.len() > 0, "`{cmd}` wrote an empty file {}", path.display());
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let bytes = || std::fs::read(path).unwrap();
    match ext.as_str() {
        "png" | "jpg" | "jpeg" => check_image(cmd, path),
        "json" => {
            serde_json::from_slice::<serde_json::Value>(&bytes()).unwrap_or_else(|e| {
                panic!("`{cmd}` wrote {} that is not JSON: {e}", path.display())
            });
        }
        "glb" => assert!(bytes().starts_with(b"glTF"), "`{cmd}`: {} is not glTF", path.display()),
        "obj" => {
            let text = String::from_utf8(bytes()).unwrap();
            assert!(
                text.lines().any(|l| l.starts_with("v "))
                    && text.lines().any(|l| l.starts_with("f ")),
                "`{cmd}`: {} has no vertices or faces",
                path.display()
            );
        }
        "svg" => {
            let text = String::from_utf8(bytes()).unwrap();
            assert!(text.contains("<svg"), "`{cmd}`: {} is not SVG", path.display());
        }
        _ => {}
    }
    1
}

/// The paths a command names as outputs: after `-o`, `--output`, `--out`, `--curvature`,
/// `--stats-json`, and after a `>` redirection.
fn output_paths(cmd: &str) -> Vec<PathBuf> {
    let words: Vec<&str> = cmd.split_whitespace().collect();
    let mut out = Vec::new();
    for w in words.windows(2) {
        if matches!(w[0], "-o" | "--output" | "--out" | "--curvature" | "--stats-json" | ">") {
            out.push(PathBuf::from(w[1]));
        }
    }
    out
}

/// Where a command writes when it names no output: `terrain bench` into `out/bench`, `terrain
/// demo` into `out/demo` (their defaults, under the git-ignored `out/`).
fn default_output(cmd: &str) -> Option<PathBuf> {
    if !output_paths(cmd).is_empty() {
        return None;
    }
    match cmd.split_whitespace().take(2).collect::<Vec<_>>()[..] {
        ["terrain", "bench"] => Some(PathBuf::from("out/bench")),
        ["terrain", "demo"] => Some(PathBuf::from("out/demo")),
        _ => None,
    }
}

/// Runs `bash -c cmd` in `dir` with `bin` first on PATH; returns (success, stdout, stderr).
fn run_shell(cmd: &str, dir: &Path, bin: &Path, logs: &Path, n: usize) -> (bool, String, String) {
    let path = std::env::join_paths(
        std::iter::once(bin.to_path_buf())
            .chain(std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default())),
    )
    .unwrap();
    let (out_path, err_path) = (logs.join(format!("{n}.out")), logs.join(format!("{n}.err")));
    let mut child = Command::new("bash")
        .args(["-e", "-o", "pipefail", "-c", cmd])
        .current_dir(dir)
        .env("PATH", path)
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .expect("bash runs");
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > COMMAND_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("README command `{cmd}` ran over {COMMAND_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let read = |p: &Path| String::from_utf8_lossy(&std::fs::read(p).unwrap()).into_owned();
    (status.success(), read(&out_path), read(&err_path))
}

/// CPU seconds (user + system) of this process's waited-for children so far, from
/// `/proc/self/stat` (`cutime`, `cstime`, at the usual 100 ticks a second); 0 where there is no
/// `/proc`. Load-independent, unlike wall time on a shared machine.
fn children_cpu_s() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return 0.0 };
    // Fields after the command name (which may hold spaces) in parentheses.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<f64> = rest.split_whitespace().map(|w| w.parse().unwrap_or(0.0)).collect();
    // `cutime` and `cstime` are fields 16 and 17 of the file, 14 and 15 after the name.
    (f.get(13).unwrap_or(&0.0) + f.get(14).unwrap_or(&0.0)) / 100.0
}

/// The shared DEMs folder: `$TERRAIN_DATA`, else `../shared/data` beside the repository.
fn data_dir() -> PathBuf {
    let dir = common::data(".");
    dir.canonicalize().unwrap_or(dir)
}

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn every_readme_command_runs_as_written() {
    let readme = std::fs::read_to_string(repo_root().join("README.md")).unwrap();
    let commands = sh_commands(&readme);
    assert!(commands.len() > 10, "only {} commands found in README.md", commands.len());

    // The allow-list cannot rot: every entry is a command of the README as it is now.
    // A reduced command writes what the README's command writes, so later commands find it.
    for (text, t) in ALLOW_LIST {
        assert!(
            commands.iter().any(|c| c.text == *text),
            "the allow-listed command `{text}` is no longer in README.md: update ALLOW_LIST"
        );
        if let Treatment::Reduced { run, .. } = t {
            assert_eq!(output_paths(run), output_paths(text), "`{run}` writes other files");
        }
    }
    // The folder the commands write into is the one .gitignore ignores.
    let gitignore = std::fs::read_to_string(repo_root().join(".gitignore")).unwrap();
    assert!(gitignore.lines().any(|l| l.trim() == "/out/"), ".gitignore does not ignore /out/");

    // A clone-like layout: ROOT/repo (the working folder, with the shipped flights) and
    // ROOT/shared/data (a link to the shared DEMs), as `../shared/data` in the README expects.
    let root = common::scratch("readme", "all");
    let repo = root.join("repo");
    let (bin, logs) = (root.join("bin"), root.join("logs"));
    for d in [&repo, &bin, &logs, &root.join("shared")] {
        std::fs::create_dir_all(d).unwrap();
    }
    std::os::unix::fs::symlink(data_dir(), root.join("shared/data")).unwrap();
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_terrain"), bin.join("terrain")).unwrap();
    copy_dir(&repo_root().join("flights"), &repo.join("flights"));
    // The README's example viewer script (its `terrain view --script` line, and the script
    // every reduced `terrain view` line runs with).
    std::fs::create_dir_all(repo.join("docs")).unwrap();
    std::fs::copy(repo_root().join("docs/view_script.txt"), repo.join("docs/view_script.txt"))
        .unwrap();
    let before = tree(&repo);

    let require_gpu = std::env::var_os("TERRAIN_REQUIRE_GPU").is_some();
    let mut report = Vec::new();
    let total = Instant::now();
    for (n, c) in commands.iter().enumerate() {
        let shown = format!("README.md:{}: {}", c.line, c.text);
        let run = match treatment(&c.text) {
            Some(Treatment::NotRun(why)) => {
                println!("NOT RUN {shown}\n    because {why}");
                report.push(format!("not run  {shown}"));
                continue;
            }
            Some(Treatment::Reduced { run, why }) => {
                println!("REDUCED {shown}\n    run as `{run}` because {why}");
                run.to_string()
            }
            None => as_run(&c.text),
        };
        let (start, cpu0) = (Instant::now(), children_cpu_s());
        let (ok, stdout, stderr) = run_shell(&run, &repo, &bin, &logs, n);
        let (secs, cpu) = (start.elapsed().as_secs_f64(), children_cpu_s() - cpu0);
        if !ok && !require_gpu && stderr.contains("no GPU adapter") {
            println!("SKIPPED {shown}: no GPU adapter; set TERRAIN_REQUIRE_GPU=1 to fail instead");
            report.push(format!("skipped  {shown} (no GPU)"));
            continue;
        }
        if !ok && !require_gpu && stderr.contains("xvfb-run: command not found") {
            println!("SKIPPED {shown}: no xvfb-run (apt-get install xvfb; .ci/run does)");
            report.push(format!("skipped  {shown} (no xvfb-run)"));
            continue;
        }
        assert!(
            ok,
            "{shown}\nfailed (ran as `{run}` in {}):\n--- stderr ---\n{stderr}\n--- stdout (end) ---\n{}",
            repo.display(),
            &stdout[stdout.len().saturating_sub(4000)..]
        );
        // What the command wrote makes sense.
        let mut checked = 0;
        for p in output_paths(&run).into_iter().chain(default_output(&run)) {
            checked += check_output(&c.text, &repo.join(p));
        }
        if c.text.starts_with("terrain info") && c.text.split_whitespace().any(|w| w == "--json") {
            serde_json::from_str::<serde_json::Value>(&stdout)
                .unwrap_or_else(|e| panic!("{shown}: stdout is not JSON: {e}\n{stdout}"));
            checked += 1;
        }
        println!("ok {secs:6.1} s wall {cpu:6.1} s CPU  {shown}  ({checked} outputs checked)");
        report.push(format!("{secs:6.1} s wall {cpu:6.1} s CPU  {shown}"));
    }
    println!(
        "\n{} README commands in {:.0} s wall, {:.0} s CPU:",
        commands.len(),
        total.elapsed().as_secs_f64(),
        children_cpu_s()
    );
    for r in &report {
        println!("  {r}");
    }

    // Nothing was written outside `out/`.
    let after = tree(&repo);
    let stray: Vec<_> =
        after.difference(&before).filter(|p| !p.starts_with("out")).map(|p| p.display()).collect();
    assert!(stray.is_empty(), "README commands wrote outside out/: {stray:?}");
}

#[test]
fn sh_blocks_are_read_as_the_shell_reads_them() {
    let readme = [
        "text",
        "```sh",
        "terrain a -o x.png   # comment",
        "",
        "terrain b \\",
        "    --c 'q # not' \\",
        "  -o y # z",
        "# only a comment",
        "```",
        "```rust",
        "not a command",
        "```",
        "```sh",
        "cargo run --release -p terrain-app -- info f.tif",
        "```",
    ]
    .join("\n");
    let readme = readme.as_str();
    let got = sh_commands(readme);
    let texts: Vec<&str> = got.iter().map(|c| c.text.as_str()).collect();
    assert_eq!(
        texts,
        [
            "terrain a -o x.png",
            "terrain b --c 'q # not' -o y",
            "cargo run --release -p terrain-app -- info f.tif"
        ]
    );
    assert_eq!(got.iter().map(|c| c.line).collect::<Vec<_>>(), [3, 5, 14]);
    assert_eq!(as_run(&got[2].text), "terrain info f.tif");
    assert_eq!(as_run(&got[0].text), "terrain a -o x.png");
    assert_eq!(
        output_paths("terrain e a.hgt -o out/e.png --curvature out/c.png"),
        [PathBuf::from("out/e.png"), PathBuf::from("out/c.png")]
    );
    assert_eq!(output_paths("grep v a.obj | cut -f2- > out/p.xyz"), [PathBuf::from("out/p.xyz")]);
    assert_eq!(default_output("terrain bench a.tif --flight f.json"), Some("out/bench".into()));
    assert_eq!(default_output("terrain bench a.tif --flight f.json -o x"), None);
    assert_eq!(default_output("terrain info a.tif"), None);
}

#[test]
fn output_checks_catch_a_blank_image_and_a_missing_file() {
    let dir = common::scratch("readme", "checks");
    let flat = dir.join("flat.png");
    image::RgbaImage::from_pixel(32, 32, image::Rgba([9, 9, 9, 255])).save(&flat).unwrap();
    let blank = std::panic::catch_unwind(|| check_output("t", &flat));
    assert!(blank.is_err(), "a flat image passed the check");
    let mut drawn = image::RgbaImage::from_pixel(32, 32, image::Rgba([9, 9, 9, 255]));
    drawn.put_pixel(1, 2, image::Rgba([200, 9, 9, 255]));
    drawn.save(&flat).unwrap();
    assert_eq!(check_output("t", &flat), 1);
    // A pyramid's 4 x 4 top level may be one colour.
    image::RgbaImage::from_pixel(4, 4, image::Rgba([9, 9, 9, 255])).save(&flat).unwrap();
    assert_eq!(check_output("t", &flat), 1);
    let missing = std::panic::catch_unwind(|| check_output("t", &dir.join("none.png")));
    assert!(missing.is_err(), "a missing output passed the check");
    std::fs::write(dir.join("bad.json"), "{").unwrap();
    assert!(std::panic::catch_unwind(|| check_output("t", &dir.join("bad.json"))).is_err());
}

#[test]
fn a_failing_command_is_seen_with_its_stderr() {
    let dir = common::scratch("readme", "shell");
    let (ok, _, stderr) = run_shell("echo said >&2; false | cat", &dir, &dir, &dir, 0);
    assert!(!ok, "a failing pipeline passed (pipefail)");
    assert_eq!(stderr.trim(), "said");
    let (ok, stdout, _) = run_shell("terrain-not-on-path || echo fine", &dir, &dir, &dir, 1);
    assert!(ok && stdout.trim() == "fine", "{stdout}");
}
