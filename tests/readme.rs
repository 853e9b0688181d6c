//! The docs cannot drift from the binary. Every command line of an `sh` block in the README and
//! in `docs/{TRAINING,DISTRIBUTED,EVALUATION}.md` that runs `fsrl ARGS` or `cargo run --release
//! -- ARGS` is run as `fsrl ARGS --help`, which must exit 0: clap refuses an unknown flag, a
//! missing subcommand or a bad value before it prints the help, and nothing else runs. The
//! README stays a front page (at most 12 KB, every relative link resolves, anchors included),
//! and its results table holds exactly the numbers of the reports it cites.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::Command;

/// The pages whose `sh` blocks are checked.
const PAGES: [&str; 5] = [
    "README.md",
    "docs/TRAINING.md",
    "docs/DISTRIBUTED.md",
    "docs/EVALUATION.md",
    "deploy/ROBOT.md",
];

/// The pages whose relative links are checked (the summary of the reproduction links into it).
const LINKED_PAGES: [&str; 7] = [
    "README.md",
    "docs/TRAINING.md",
    "docs/DISTRIBUTED.md",
    "docs/EVALUATION.md",
    "docs/REPRODUCTION.md",
    "docs/CROWDS.md",
    "deploy/ROBOT.md",
];

/// How many `fsrl` lines may use what the check cannot run without a shell (pipes,
/// substitutions, redirections, `&&`).
const MAX_SKIPPED: usize = 2;

/// The front page's limit, in bytes.
const README_MAX_BYTES: u64 = 12_000;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn read(page: &str) -> String {
    let path = root().join(page);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// One command line of an `sh` block: where it starts and its text, continuations joined.
#[derive(Debug)]
struct Line {
    page: &'static str,
    number: usize,
    text: String,
}

/// The command lines of every `sh` (or `bash`, `shell`) block of `text`; a line ending in `\`
/// continues on the next.
fn sh_lines(page: &'static str, text: &str) -> Vec<Line> {
    let mut lines = Vec::new();
    let mut fence: Option<bool> = None; // inside a block: is it shell?
    let mut pending: Option<Line> = None;
    for (i, raw) in text.lines().enumerate() {
        let trimmed = raw.trim_start();
        if let Some(info) = trimmed.strip_prefix("```") {
            fence = match fence {
                None => Some(matches!(info.trim(), "sh" | "bash" | "shell")),
                Some(_) => None,
            };
            if let Some(line) = pending.take() {
                lines.push(line);
            }
            continue;
        }
        if fence != Some(true) {
            continue;
        }
        let (body, continues) = match raw.strip_suffix('\\') {
            Some(body) => (body, true),
            None => (raw, false),
        };
        match &mut pending {
            Some(line) => {
                line.text.push(' ');
                line.text.push_str(body);
            }
            None => {
                pending = Some(Line {
                    page,
                    number: i + 1,
                    text: body.to_string(),
                })
            }
        }
        if !continues {
            lines.extend(pending.take());
        }
    }
    lines
}

/// A shell word or an operator.
#[derive(Debug, PartialEq)]
enum Token {
    Word(String),
    /// `|`, `||`, `&`, `&&`, `;`, `<`, `>`, `>>`: more than one command, or a redirection.
    Operator,
}

/// The words of a command line as a POSIX shell splits them (quotes removed, a `#` starting a
/// word begins a comment), and whether it holds a substitution (`$`, a backquote), which only a
/// shell can expand. Brace expansions and globs stay literal: `--help` does not read them.
fn tokenize(line: &str) -> (Vec<Token>, bool) {
    let mut tokens = Vec::new();
    let mut substitution = false;
    let mut word: Option<String> = None;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            c if c.is_whitespace() => tokens.extend(word.take().map(Token::Word)),
            '#' if word.is_none() => break,
            '\'' => {
                let w = word.get_or_insert_with(String::new);
                for q in chars.by_ref() {
                    if q == '\'' {
                        break;
                    }
                    w.push(q);
                }
            }
            '"' => {
                let w = word.get_or_insert_with(String::new);
                while let Some(q) = chars.next() {
                    match q {
                        '"' => break,
                        '\\' => w.extend(chars.next()),
                        '$' | '`' => {
                            substitution = true;
                            w.push(q);
                        }
                        _ => w.push(q),
                    }
                }
            }
            '\\' => word.get_or_insert_with(String::new).extend(chars.next()),
            '$' | '`' => {
                substitution = true;
                word.get_or_insert_with(String::new).push(c);
            }
            '|' | '&' | ';' | '<' | '>' => {
                tokens.extend(word.take().map(Token::Word));
                while chars.next_if(|n| matches!(n, '|' | '&' | '>')).is_some() {}
                tokens.push(Token::Operator);
            }
            _ => word.get_or_insert_with(String::new).push(c),
        }
    }
    tokens.extend(word.map(Token::Word));
    (tokens, substitution)
}

/// The arguments after `fsrl` when `words` run the fsrl binary (`fsrl ARGS` or `cargo run
/// --release -- ARGS`, after environment assignments and `sudo [-u USER]`).
fn fsrl_args(words: &[String]) -> Option<Vec<String>> {
    let mut rest = words;
    while let Some(first) = rest.first() {
        if first.contains('=') && !first.starts_with('-') {
            rest = &rest[1..];
        } else if first == "sudo" {
            rest = match rest.get(1).map(String::as_str) {
                Some("-u") => rest.get(3..).unwrap_or_default(),
                _ => &rest[1..],
            };
        } else {
            break;
        }
    }
    match rest {
        [fsrl, args @ ..] if fsrl == "fsrl" || fsrl.ends_with("/fsrl") => Some(args.to_vec()),
        [cargo, run, release, dashes, args @ ..]
            if cargo == "cargo" && run == "run" && release == "--release" && dashes == "--" =>
        {
            Some(args.to_vec())
        }
        _ => None,
    }
}

/// What the check does with one command line.
#[derive(Debug, PartialEq)]
enum Verdict {
    /// Runs the binary with these arguments.
    Run(Vec<String>),
    /// Runs the binary but needs a shell to say how.
    Skip,
    /// Does not run the binary.
    Other,
}

fn verdict(line: &str) -> Verdict {
    let (tokens, substitution) = tokenize(line);
    let segments: Vec<Vec<String>> = tokens
        .split(|t| *t == Token::Operator)
        .map(|seg| {
            seg.iter()
                .filter_map(|t| match t {
                    Token::Word(w) => Some(w.clone()),
                    Token::Operator => None,
                })
                .collect()
        })
        .collect();
    let runs: Vec<Vec<String>> = segments.iter().filter_map(|s| fsrl_args(s)).collect();
    match runs.as_slice() {
        [] => Verdict::Other,
        [args] if segments.len() == 1 && !substitution => Verdict::Run(args.clone()),
        _ => Verdict::Skip,
    }
}

#[test]
fn every_documented_command_parses() {
    let mut ran = 0;
    let mut skipped = Vec::new();
    let mut failures = Vec::new();
    for page in PAGES {
        for line in sh_lines(page, &read(page)) {
            let args = match verdict(&line.text) {
                Verdict::Run(args) => args,
                Verdict::Skip => {
                    skipped.push(format!("{}:{}: {}", line.page, line.number, line.text));
                    continue;
                }
                Verdict::Other => continue,
            };
            ran += 1;
            let out = Command::new(env!("CARGO_BIN_EXE_fsrl"))
                .args(&args)
                .arg("--help")
                .current_dir(root())
                .output()
                .unwrap();
            if !out.status.success() {
                failures.push(format!(
                    "{}:{}: {}\n    fsrl {} --help: {}\n    {}",
                    line.page,
                    line.number,
                    line.text.trim(),
                    args.join(" "),
                    out.status,
                    String::from_utf8_lossy(&out.stderr)
                        .trim()
                        .replace('\n', "\n    ")
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {ran} documented commands do not parse:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(
        skipped.len() <= MAX_SKIPPED,
        "{} documented fsrl commands need a shell and are not checked (at most {MAX_SKIPPED}):\n{}",
        skipped.len(),
        skipped.join("\n")
    );
    // A parser that finds nothing would pass everything.
    assert!(ran >= 40, "only {ran} documented commands found");
    println!(
        "{ran} documented commands parse; {} need a shell and are not run",
        skipped.len()
    );
}

#[test]
fn the_readme_is_a_front_page() {
    let len = std::fs::metadata(root().join("README.md")).unwrap().len();
    assert!(
        len <= README_MAX_BYTES,
        "README.md is {len} bytes; at most {README_MAX_BYTES}: move the details to docs/"
    );
}

/// GitHub's anchor of a heading: lower case, letters, digits, `-`, `_` and spaces kept, spaces
/// made hyphens.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, '-' | '_' | ' '))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of a Markdown page's headings (not of `#` lines inside code blocks); a repeated
/// heading gets `-1`, `-2`, ... as on GitHub.
fn anchors(text: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut in_code = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
            continue;
        }
        if in_code {
            continue;
        }
        let hashes = line.chars().take_while(|&c| c == '#').count();
        if hashes == 0 || hashes > 6 || !line[hashes..].starts_with(' ') {
            continue;
        }
        let base = slug(&line[hashes..]);
        let mut anchor = base.clone();
        let mut n = 0;
        while seen.contains(&anchor) {
            n += 1;
            anchor = format!("{base}-{n}");
        }
        seen.insert(anchor);
    }
    seen
}

/// The targets of the Markdown links and images of `text`, outside code.
fn link_targets(text: &str) -> Vec<String> {
    let mut targets = Vec::new();
    let mut in_code = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
            continue;
        }
        if in_code {
            continue;
        }
        // Inline code spans may hold `](`; drop them first.
        let plain: String = line
            .split('`')
            .enumerate()
            .filter(|(i, _)| i % 2 == 0)
            .map(|(_, s)| s)
            .collect();
        let mut rest = plain.as_str();
        while let Some(i) = rest.find("](") {
            let after = &rest[i + 2..];
            match after.find(')') {
                Some(j) => {
                    targets.push(after[..j].trim().to_string());
                    rest = &after[j + 1..];
                }
                None => break,
            }
        }
    }
    targets
}

#[test]
fn every_relative_link_resolves() {
    let mut broken = Vec::new();
    let mut checked = 0;
    for page in LINKED_PAGES {
        let text = read(page);
        let dir = root().join(page).parent().unwrap().to_path_buf();
        for target in link_targets(&text) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            let (path, fragment) = match target.split_once('#') {
                Some((p, f)) => (p, Some(f)),
                None => (target.as_str(), None),
            };
            let file = if path.is_empty() {
                root().join(page)
            } else {
                dir.join(path)
            };
            if !file.exists() {
                broken.push(format!("{page}: {target}: no {}", file.display()));
                continue;
            }
            if let Some(fragment) = fragment {
                if file.extension().is_some_and(|e| e == "md")
                    && !anchors(&std::fs::read_to_string(&file).unwrap()).contains(fragment)
                {
                    broken.push(format!("{page}: {target}: no heading #{fragment}"));
                }
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
    assert!(checked >= 20, "only {checked} links found");
}

/// The cells of one Markdown table row, trimmed.
fn cells(line: &str) -> Vec<String> {
    line.trim()
        .trim_matches('|')
        .split('|')
        .map(|c| c.trim().to_string())
        .collect()
}

/// The cells of the Markdown table under the heading starting with `section` in `text`, as
/// rows of cells (header row first, the `|---|` row left out).
fn table(text: &str, section: &str) -> Vec<Vec<String>> {
    let start = text
        .lines()
        .position(|l| l.starts_with("## ") && l[3..].starts_with(section))
        .unwrap_or_else(|| panic!("no section `## {section}`"));
    text.lines()
        .skip(start + 1)
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .filter(|l| !l.starts_with("|---"))
        .map(cells)
        .collect()
}

/// The value of `row` (the first cell starting with it) in `column` of `table`, up to its
/// first space (a mean without its ± or interval).
fn cell(table: &[Vec<String>], row: &str, column: &str) -> String {
    let c = table[0]
        .iter()
        .position(|h| h == column)
        .unwrap_or_else(|| panic!("no column {column}"));
    let r = table
        .iter()
        .find(|r| r[0] == row || r[0].starts_with(&format!("{row} (n=")))
        .unwrap_or_else(|| panic!("no row {row}"));
    r[c].split(' ').next().unwrap().to_string()
}

#[test]
fn the_readme_results_are_the_reports_numbers() {
    let readme = read("README.md");
    let header = "| setting | method | Succ. | Nav. Time (s) | paper | Disc. | paper |";
    let rows: Vec<Vec<String>> = readme
        .lines()
        .skip_while(|l| *l != header)
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(cells)
        .collect();
    // The paper's six first; then beyond the paper, the walled settings (issue 53).
    let walled_from = rows
        .iter()
        .position(|r| {
            r[0].parse::<sim::Setting>()
                .is_ok_and(|s| s.env.is_walled())
        })
        .unwrap_or(rows.len());
    let (rows, walled) = rows.split_at(walled_from);
    assert_eq!(rows.len(), 30, "six settings × four methods and fsrl-plan");
    walled_rows_are_the_reports_numbers(walled);
    let grid = read("docs/results/grid-compare/compare.md");
    // Beyond the paper: fsrl-plan's 18 shipped models (Experiment 25); its report has no paper
    // rows, so its paper columns are FSRL's from the grid's report.
    let plan = read("docs/results/fsrl-plan/compare-six/compare.md");
    let six = read("docs/pictures/eval.md");
    let mut setting = String::new();
    for row in rows {
        if !row[0].is_empty() {
            setting = row[0].clone();
        }
        let (env, visibility) = setting.split_once('-').unwrap();
        let column = format!(
            "{}. Env {}",
            &visibility[..3],
            env.trim_start_matches("env")
        );
        // ORCA is in the evaluation on all six settings; the trained methods in the grid's
        // comparison, each in its own setting.
        let (report, ours, paper_report, paper) = match row[1].as_str() {
            "ORCA" => (&six, "orca", &six, "ORCA (paper)"),
            "LSTM-RL" => (&grid, "lstm-rl", &grid, "LSTM-RL (paper)"),
            "SARL" => (&grid, "sarl", &grid, "SARL (paper)"),
            "FSRL" => (&grid, "fsrl", &grid, "FSRL (paper)"),
            "**fsrl-plan** †" => (&plan, "fsrl-plan", &grid, "FSRL (paper)"),
            other => panic!("unknown method {other}"),
        };
        let expected = [
            cell(&table(report, "Succ."), ours, &column),
            cell(&table(report, "Nav. Time"), ours, &column),
            cell(&table(paper_report, "Nav. Time"), paper, &column),
            cell(&table(report, "Disc."), ours, &column),
            cell(&table(paper_report, "Disc."), paper, &column),
        ];
        assert_eq!(row[2..], expected, "{setting} {}", row[1]);
    }
}

/// The first cell (up to its first space) of `column` in the row of the Markdown table with
/// `header` whose cells `key` match, as `(key column, value)` pairs.
fn md_cell(text: &str, header: &str, key: &[(&str, &str)], column: &str) -> String {
    let mut lines = text.lines().skip_while(|l| !l.starts_with(header));
    let head = cells(lines.next().unwrap_or_else(|| panic!("no table {header}")));
    let at = |name: &str| {
        head.iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no column {name} in {header}"))
    };
    let row = lines
        .take_while(|l| l.starts_with('|'))
        .map(cells)
        .find(|r| key.iter().all(|(k, v)| r[at(k)] == *v))
        .unwrap_or_else(|| panic!("no row {key:?} in {header}"));
    row[at(column)].split(' ').next().unwrap().to_string()
}

/// The walled settings' rows (issue 53): ORCA from the walled baselines' evaluation, FSRL from
/// the report of the model trained in that setting (seed 0, `models/fsrl-<setting>-s0.fsrlm`);
/// no paper columns (the paper has no walls).
fn walled_rows_are_the_reports_numbers(rows: &[Vec<String>]) {
    let orca = read("docs/results/walls-baselines-shield/eval.md");
    let mut setting = String::new();
    let mut seen = BTreeSet::new();
    for row in rows {
        if !row[0].is_empty() {
            setting = row[0].clone();
        }
        assert!(
            setting
                .parse::<sim::Setting>()
                .is_ok_and(|s| s.env.is_walled()),
            "{setting}: after the paper's six only walled settings"
        );
        let got = |column: &str| match row[1].as_str() {
            "ORCA" => md_cell(
                &orca,
                "| method | setting |",
                &[("method", "orca"), ("setting", &setting)],
                column,
            ),
            "FSRL ‡" => walled_mean(&setting, column),
            other => panic!("{setting}: unknown method {other}"),
        };
        let expected = [
            got("Succ."),
            got("Nav. Time (s)"),
            "–".to_string(),
            got("Disc."),
            "–".to_string(),
        ];
        assert_eq!(row[2..], expected, "{setting} {}", row[1]);
        seen.insert((setting.clone(), row[1].clone()));
    }
    assert!(
        seen.len() >= 2,
        "the walled settings have rows in the README: {seen:?}"
    );
}

/// The README's walled FSRL row: the mean over seeds 0, 1 and 2 of `column` in the reports
/// `docs/results/walls/fsrl-SETTING-sN/report.json`, each seed's model shipped.
fn walled_mean(setting: &str, column: &str) -> String {
    let (field, digits) = match column {
        "Succ." => ("success", 3),
        "Nav. Time (s)" => ("nav_time_s", 2),
        "Disc." => ("disc", 3),
        other => panic!("no walled column {other}"),
    };
    let values: Vec<f64> = (0..3)
        .map(|seed| {
            assert!(
                root()
                    .join(format!("models/fsrl-{setting}-s{seed}.fsrlm"))
                    .exists(),
                "{setting}: the seed-{seed} model ships"
            );
            let path = format!("docs/results/walls/fsrl-{setting}-s{seed}/report.json");
            let report: serde_json::Value = serde_json::from_str(&read(&path)).unwrap();
            let row = report["settings"]
                .as_array()
                .unwrap()
                .iter()
                .find(|r| r["setting"] == setting)
                .unwrap_or_else(|| panic!("{path}: no {setting}"))
                .clone();
            row[field].as_f64().unwrap()
        })
        .collect();
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    format!("{mean:.digits$}")
}

#[test]
fn the_line_reader_understands_the_shell_it_skips() {
    assert_eq!(
        verdict("fsrl eval runs/a --out 'x y'   # a comment --bogus"),
        Verdict::Run(vec![
            "eval".into(),
            "runs/a".into(),
            "--out".into(),
            "x y".into()
        ])
    );
    assert_eq!(
        verdict("cargo run --release -- train --seed 1"),
        Verdict::Run(vec!["train".into(), "--seed".into(), "1".into()])
    );
    assert_eq!(
        verdict("sudo -u fsrl-monitor fsrl watch --run cluster"),
        Verdict::Run(vec!["watch".into(), "--run".into(), "cluster".into()])
    );
    assert_eq!(verdict("fsrl compare a b > out.md"), Verdict::Skip);
    assert_eq!(verdict("fsrl eval $(ls runs)"), Verdict::Skip);
    assert_eq!(
        verdict("pip install msgpack && python3 tools/watch_metrics.py"),
        Verdict::Other
    );
    assert_eq!(verdict("tools/test.sh -p proto"), Verdict::Other);
    let text = "```sh\nfsrl plot bars a.json \\\n  --out x\n```\n```text\nfsrl nope\n```\n";
    let lines = sh_lines("t.md", text);
    assert_eq!(lines.len(), 1);
    assert_eq!(lines[0].number, 2);
    assert_eq!(
        verdict(&lines[0].text),
        Verdict::Run(vec![
            "plot".into(),
            "bars".into(),
            "a.json".into(),
            "--out".into(),
            "x".into()
        ])
    );
    assert_eq!(
        slug("Experiment 4: what breaks FSRL in Env 3 (three arms × three seeds, env3-invisible)"),
        "experiment-4-what-breaks-fsrl-in-env-3-three-arms--three-seeds-env3-invisible"
    );
}
