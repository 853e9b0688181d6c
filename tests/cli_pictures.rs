//! `fsrl eval`, `fsrl compare` and `fsrl plot` end to end on tiny runs: the reports carry every
//! metric with its intervals and the paper's numbers, and every kind of picture is a valid,
//! non-trivial SVG, PNG or GIF with the expected bars, series and frames. Bad inputs give clear
//! errors. Set `FSRL_PICTURES_KEEP=dir` to keep the pictures for a look.

mod cli_support;
use cli_support::{fails, fsrl, ok, s};

use std::collections::HashSet;
use std::path::{Path, PathBuf};

fn train(dir: &Path, method: &str, name: &str) -> PathBuf {
    let out = dir.join(name);
    // The run's policy is its last weights (these tests are about reports and pictures; the
    // selection rules have their own tests in cli_train.rs).
    let last = dir.join("last.toml");
    std::fs::write(&last, "[train]\nselect = \"last\"\n").unwrap();
    ok(&[
        "train",
        "--single-process",
        "--config",
        s(&last),
        "--method",
        method,
        "--setting",
        "env2-invisible",
        "--il-episodes",
        "6",
        "--il-epochs",
        "2",
        "--rl-episodes",
        "3",
        "--eval-episodes",
        "3",
        "--out",
        s(&out),
    ]);
    out
}

struct Svg {
    width: f64,
    height: f64,
    fills: Vec<String>,
    wide_polylines: usize,
    text: String,
}

fn svg(path: &Path) -> Svg {
    let src = std::fs::read_to_string(path).unwrap();
    let doc = roxmltree::Document::parse(&src)
        .unwrap_or_else(|e| panic!("{}: invalid SVG: {e}", path.display()));
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "svg");
    let mut out = Svg {
        width: root.attribute("width").unwrap().parse().unwrap(),
        height: root.attribute("height").unwrap().parse().unwrap(),
        fills: Vec::new(),
        wide_polylines: 0,
        text: String::new(),
    };
    for n in doc.descendants() {
        match n.tag_name().name() {
            "rect" | "polygon" => out
                .fills
                .push(n.attribute("fill").unwrap_or("").to_uppercase()),
            "polyline" if n.attribute("stroke-width") == Some("2") => out.wide_polylines += 1,
            "text" => {
                out.text.push_str(n.text().unwrap_or(""));
                out.text.push('\n');
            }
            _ => {}
        }
    }
    assert!(out.width > 300.0 && out.height > 200.0);
    out
}

/// Decodes a PNG: its size equals the SVG's, and it is not blank.
fn png(path: &Path, svg: &Svg) {
    let mut reader = png::Decoder::new(std::fs::File::open(path).unwrap())
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(
        (info.width as f64, info.height as f64),
        (svg.width, svg.height)
    );
    let colours: HashSet<&[u8]> = buf[..info.buffer_size()]
        .chunks(info.color_type.samples())
        .collect();
    assert!(colours.len() > 20, "{}: nearly blank", path.display());
}

fn count(fills: &[String], colour: &str) -> usize {
    fills.iter().filter(|f| *f == colour).count()
}

fn keep(dir: &Path) {
    if let Some(k) = std::env::var_os("FSRL_PICTURES_KEEP") {
        std::fs::create_dir_all(&k).unwrap();
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_file() {
                std::fs::copy(&p, Path::new(&k).join(p.file_name().unwrap())).unwrap();
            }
        }
    }
}

#[test]
fn reports_and_every_picture_from_tiny_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let sarl = train(dir, "sarl", "sarl-s0");
    let fsrl_run = train(dir, "fsrl", "fsrl-s0");

    // eval: one run directory → RUN/eval/; the numbers equal the train report's on its setting.
    ok(&["eval", s(&sarl), "--episodes", "3", "--threads", "2"]);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sarl.join("eval/eval.json")).unwrap())
            .unwrap();
    assert_eq!(json["kind"], "fsrl eval");
    let subject = &json["subjects"][0];
    assert_eq!(subject["method"], "sarl");
    let settings = subject["settings"].as_array().unwrap();
    assert_eq!(settings.len(), 6);
    let train_report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sarl.join("report.json")).unwrap()).unwrap();
    let trained = &train_report["settings"][0];
    let same = settings
        .iter()
        .find(|r| r["setting"] == "env2-invisible")
        .unwrap();
    for key in [
        "success",
        "collision",
        "timeout",
        "disc",
        "mean_return",
        "nav_time_s",
    ] {
        assert_eq!(same[key], trained[key], "{key}");
    }
    for r in settings {
        let [lo, hi] = [
            r["success_ci95"][0].as_f64().unwrap(),
            r["success_ci95"][1].as_f64().unwrap(),
        ];
        let p = r["success"].as_f64().unwrap();
        assert!(lo <= p && p <= hi, "{r}");
    }
    let md = std::fs::read_to_string(sarl.join("eval/eval.md")).unwrap();
    assert!(md.contains(
        "| SARL (paper) | 12.25 | 11.39 | 11.15 | 11.60 | 9.85 | 10.33 | 10.01 | 10.06 |"
    ));
    let csv = std::fs::read_to_string(sarl.join("eval/eval.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 6);
    assert!(csv.starts_with("label,method,checkpoint,"));

    // eval of ORCA and a checkpoint file together, into --out.
    let both = dir.join("both");
    ok(&[
        "eval",
        "--orca",
        s(&fsrl_run.join("checkpoints/latest.ckpt")),
        "--episodes",
        "3",
        "--out",
        s(&both),
    ]);
    let csv = std::fs::read_to_string(both.join("eval.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 2 * 6);
    assert!(csv.contains("\norca,orca,,0,"));

    // compare: a run directory with eval/, one with only report.json, and an eval.json.
    let cmp = dir.join("cmp");
    let table = ok(&[
        "compare",
        s(&sarl),
        s(&fsrl_run),
        s(&both.join("eval.json")),
        "--out",
        s(&cmp),
    ]);
    assert!(table.contains("| orca (n=1) |"));
    assert!(table.contains("| sarl (n=1) |"));
    // fsrl's run is met twice (its report.json and both/eval.json): counted once, with the
    // record that covers all six settings.
    assert!(table.contains("| fsrl (n=1) |"), "{table}");
    let succ_row = table
        .lines()
        .find(|l| l.starts_with("| fsrl (n=1) |"))
        .unwrap();
    assert!(!succ_row.contains('–'), "{succ_row}");
    assert!(table.contains("| ORCA (paper) | 12.49 |"));
    for f in ["compare.md", "compare.csv", "compare.json"] {
        assert!(cmp.join(f).is_file());
    }

    // Pictures.
    let pics = dir.join("pics");
    ok(&[
        "plot",
        "bars",
        s(&sarl),
        s(&both.join("eval.json")),
        "--out",
        s(&pics.join("bars")),
    ]);
    let bars = svg(&pics.join("bars.svg"));
    // 6 settings × 3 methods, one bar per outcome, plus the legend's square.
    assert_eq!(count(&bars.fills, "#2CA02C"), 18 + 1);
    assert_eq!(count(&bars.fills, "#D62728"), 18 + 1);
    assert_eq!(count(&bars.fills, "#FF9F1C"), 18 + 1);
    assert!(bars.text.contains("Env 3 (visible)"));
    png(&pics.join("bars.png"), &bars);

    ok(&[
        "plot",
        "curves",
        s(&sarl),
        s(&fsrl_run),
        "--window",
        "2",
        "--out",
        s(&pics.join("curves")),
    ]);
    let curves = svg(&pics.join("curves.svg"));
    assert_eq!(curves.wide_polylines, 4 * 2, "4 panels × 2 runs");
    assert!(curves.text.contains("sarl-s0") && curves.text.contains("fsrl-s0"));
    png(&pics.join("curves.png"), &curves);
    // The validation lines `fsrl train` wrote (if its config validates) make two more pictures.
    let validated = |run: &Path| {
        std::fs::read_to_string(run.join("metrics.jsonl"))
            .unwrap()
            .contains(r#""phase":"validation""#)
    };
    for stem in ["curves-validation-episodes", "curves-validation-time"] {
        let file = pics.join(format!("{stem}.svg"));
        assert_eq!(
            file.exists(),
            validated(&sarl) || validated(&fsrl_run),
            "{stem}"
        );
        if file.exists() {
            let v = svg(&file);
            assert!(v.text.contains("validation success rate"));
            for (run, label) in [(&sarl, "sarl-s0"), (&fsrl_run, "fsrl-s0")] {
                assert_eq!(v.text.contains(label), validated(run), "{label} in {stem}");
            }
            png(&pics.join(format!("{stem}.png")), &v);
        }
    }

    ok(&[
        "plot",
        "ablation",
        s(&sarl),
        s(&both.join("eval.json")),
        "--out",
        s(&pics.join("ablation")),
    ]);
    let abl = svg(&pics.join("ablation.svg"));
    // sarl and fsrl have results; +R_f and +R_t have none (no bars).
    assert_eq!(count(&abl.fills, "#2CA02C"), 2 + 1);
    assert_eq!(count(&abl.fills, "#9467BD"), 2 + 1, "Disc. bars");
    // Nav. Time only where a tiny run had a success.
    assert!(count(&abl.fills, "#1F77B4") <= 2 + 1);
    for w in [
        "R_c (sarl) (1)",
        "+R_f (0)",
        "all (fsrl) (1)",
        "Nav. Time",
        "Disc.",
    ] {
        assert!(abl.text.contains(w), "missing {w}");
    }
    png(&pics.join("ablation.png"), &abl);

    let out = ok(&[
        "plot",
        "episode",
        s(&fsrl_run),
        "--seed",
        "1002",
        "--times",
        "1,3",
        "--gif-size",
        "200",
        "--out",
        s(&pics.join("episode")),
    ]);
    assert!(out.contains("episode.gif"));
    let ep = svg(&pics.join("episode.svg"));
    assert!(ep.text.contains("t = 1.00 s") && ep.text.contains("t = 3.00 s"));
    assert!(ep.text.contains("attention"));
    // Every one of the 10 humans has its weight printed in both panels.
    let weights = ep
        .text
        .lines()
        .filter(|l| l.len() == 4 && l.starts_with("0."))
        .count();
    assert!(weights >= 2 * 10, "{weights} weights");
    png(&pics.join("episode.png"), &ep);
    let mut gif = gif::DecodeOptions::new()
        .read_info(std::fs::File::open(pics.join("episode.gif")).unwrap())
        .unwrap();
    let mut frames = 0;
    while gif.read_next_frame().unwrap().is_some() {
        frames += 1;
    }
    assert!(frames > 8 + 4, "{frames} frames");

    ok(&[
        "plot",
        "episode",
        "--orca",
        "--setting",
        "env3-visible",
        "--no-gif",
        "--out",
        s(&pics.join("orca")),
    ]);
    let orca = svg(&pics.join("orca.svg"));
    assert!(orca.text.contains("no attention"));
    assert!(!pics.join("orca.gif").exists());
    keep(&pics);
}

/// A validation line as `fsrl train` writes it.
fn validation_line(episode: u64, success: f64, wall_s: f64) -> String {
    format!(
        r#"{{"phase":"validation","episode":{episode},"env_steps":{},"policy_version":{},"episodes":100,"seed_start":0,"success_rate":{success},"collision_rate":{},"timeout_rate":0.0,"discomfort":0.1,"nav_time_s":12.5,"mean_return":0.2,"wall_s":{wall_s}}}"#,
        40 * episode,
        episode + 20,
        1.0 - success
    )
}

fn rl_line(episode: u64, wall_s: f64) -> String {
    format!(
        r#"{{"phase":"rl","episode":{episode},"epsilon":0.3,"outcome":"collision","steps":20,"return_sum":-0.25,"loss":0.02,"success_rate_window":0.0,"collision_rate_window":1.0,"timeout_rate_window":0.0,"policy_version":{episode},"env_steps":{},"replay_size":500,"wall_s":{wall_s}}}"#,
        20 * episode
    )
}

#[test]
fn validation_curves_put_the_seeds_of_a_method_together() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let write = |name: &str, lines: &[String]| {
        let run = dir.join(name);
        std::fs::create_dir_all(&run).unwrap();
        std::fs::write(run.join("metrics.jsonl"), lines.join("\n") + "\n").unwrap();
        run
    };
    let mut runs = Vec::new();
    for (seed, speed) in [(0, 1.0), (1, 1.5)] {
        let mut lines = Vec::new();
        for k in 0..=20 {
            if k % 10 == 0 {
                lines.push(validation_line(
                    k,
                    k as f64 / 25.0,
                    speed * (60.0 + 10.0 * k as f64),
                ));
            }
            lines.push(rl_line(k, speed * (61.0 + 10.0 * k as f64)));
        }
        // Resumed after episode 10: the last validation at 20 is the one that counts.
        lines.push(validation_line(20, 0.9, speed * 500.0));
        runs.push(write(&format!("fsrl-env1-invisible-s{seed}"), &lines));
    }
    runs.push(write(
        "sarl-env1-invisible-s0",
        &[
            validation_line(0, 0.0, 30.0),
            validation_line(10, 0.5, 400.0),
        ],
    ));
    runs.push(write("old-run", &[rl_line(0, 1.0), rl_line(1, 2.0)]));
    // Stopped while appending a line: the line is left out with a warning, the log is drawn.
    let old_log = runs[3].join("metrics.jsonl");
    let whole = std::fs::read_to_string(&old_log).unwrap();
    std::fs::write(&old_log, whole + "{\"phase\":\"rl\",\"epis").unwrap();
    let out = dir.join("pics").join("c");
    let mut args = vec!["plot", "curves"];
    args.extend(runs.iter().map(|r| s(r)));
    args.extend(["--out", s(&out)]);
    let o = fsrl(&args);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(
        stderr.contains("note: old-run has no validation lines"),
        "{stderr}"
    );
    for (stem, axis) in [
        ("c-validation-episodes", "RL episodes trained"),
        ("c-validation-time", "wall-clock time (min)"),
    ] {
        assert!(stdout.contains(&format!("{stem}.png")), "{stdout}");
        let v = svg(&dir.join("pics").join(format!("{stem}.svg")));
        for word in [
            axis,
            "fsrl-env1-invisible (2 runs)",
            "sarl-env1-invisible-s0",
            "min–max",
        ] {
            assert!(v.text.contains(word), "missing {word} in {stem}");
        }
        assert!(!v.text.contains("old-run"), "{stem}");
        // Two groups, three panels: at least a line per group and panel.
        assert!(v.wide_polylines >= 2 * 3, "{stem}: {}", v.wide_polylines);
        png(&dir.join("pics").join(format!("{stem}.png")), &v);
    }
    assert!(
        stderr.contains("old-run/metrics.jsonl: the last line is cut short"),
        "{stderr}"
    );
    let all = svg(&dir.join("pics").join("c.svg"));
    assert!(all.text.contains("old-run") && all.text.contains("fsrl-env1-invisible-s1"));

    // Without any validation line: today's picture alone, and a note.
    let o = fsrl(&["plot", "curves", s(&runs[3]), "--out", s(&dir.join("old"))]);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no validation curves drawn"));
    assert!(dir.join("old.svg").exists() && !dir.join("old-validation-time.svg").exists());
    keep(&dir.join("pics"));
}

/// `fsrl plot frontier` on two low-disc runs of one setting: every good snapshot a dot, the
/// shipped one ringed, the paper's rows as crosses, and a table that counts the snapshots as
/// fast and as gentle as the paper's row.
#[test]
fn frontier_counts_the_snapshots_that_reach_the_papers_point() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let line = |ep: u64, success: f64, nav: f64, disc: f64| {
        format!(
            r#"{{"phase":"validation","episode":{ep},"success_rate":{success},"collision_rate":0.0,"timeout_rate":0.0,"discomfort":{disc},"nav_time_s":{nav},"mean_return":0.5,"wall_s":1.0}}"#
        )
    };
    let run = |method: &str, lines: &[String]| {
        let run = dir.join(format!("{method}-env1-visible-s0"));
        std::fs::create_dir_all(run.join("checkpoints/validation")).unwrap();
        std::fs::write(
            run.join("config.toml"),
            format!("[run]\nmethod = \"{method}\"\nsetting = \"env1-visible\"\n[train]\nselect = \"low-disc\"\n[train.rl]\nepsilon_decay_episodes = 100\n"),
        )
        .unwrap();
        std::fs::write(run.join("metrics.jsonl"), lines.join("\n") + "\n").unwrap();
        for ep in [0, 100, 200, 300] {
            std::fs::write(
                run.join(format!("checkpoints/validation/ep-{ep:06}.fsrlm")),
                b"x",
            )
            .unwrap();
        }
        run
    };
    // The paper's env1-visible rows: FSRL 11.08 s / 0.06, SARL 9.85 s / 0.09.
    let fsrl_run = run(
        "fsrl",
        &[
            line(0, 1.0, 9.0, 0.0),      // before the decay: not a candidate
            line(100, 0.97, 11.0, 0.05), // reaches FSRL's point
            line(200, 0.99, 12.0, 0.03), // the gentlest: shipped
            line(300, 0.94, 10.0, 0.01), // success too low
        ],
    );
    let sarl_run = run(
        "sarl",
        &[line(100, 0.96, 10.5, 0.08), line(200, 0.98, 11.5, 0.07)],
    );
    let out = dir.join("pics").join("f");
    let stdout = ok(&[
        "plot",
        "frontier",
        s(&fsrl_run),
        s(&sarl_run),
        "--out",
        s(&out),
    ]);
    assert!(
        stdout.contains("| fsrl-env1-visible-s0 | fsrl | env1-visible | 0 | 2 | 11.00 s / 0.050 (ep 100) | 12.00 s / 0.030 (ep 200) | 12.00 s / 0.030 (ep 200) | 11.08 s / 0.06 | 1 |"),
        "{stdout}"
    );
    assert!(
        stdout.contains("| sarl-env1-visible-s0 | sarl | env1-visible | 0 | 2 |"),
        "{stdout}"
    );
    assert!(
        stdout.contains("1 of 4 snapshots in 2 runs reach"),
        "{stdout}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("pics/f.md")).unwrap(),
        stdout
            .lines()
            .take_while(|l| !l.starts_with("written:"))
            .collect::<Vec<_>>()
            .join("\n")
            + "\n"
    );
    let src = std::fs::read_to_string(dir.join("pics/f.svg")).unwrap();
    let v = svg(&dir.join("pics/f.svg"));
    assert!(v.text.contains("env1-visible") && v.text.contains("Nav. Time (s)"));
    // 4 snapshot dots and 2 rings.
    assert_eq!(src.matches("<circle").count(), 4 + 2);
    png(&dir.join("pics/f.png"), &v);

    // --pick common-speed: one snapshot a run, nothing written. The good snapshots' times are
    // 11 and 12 s (FSRL), 10.5 and 11.5 s (SARL): T* = 11.25 s, and each run's gentlest no
    // slower is its first (FSRL's gentlest overall, 12 s, is too slow).
    let g = dir.join("g");
    let picked = ok(&[
        "plot",
        "frontier",
        s(&fsrl_run),
        s(&sarl_run),
        "--pick",
        "common-speed",
        "--out",
        s(&g),
    ]);
    assert_eq!(
        picked,
        format!(
            "{}\t100\t11.250\tgentlest-at-or-below\n{}\t100\t11.250\tgentlest-at-or-below\n",
            fsrl_run.display(),
            sarl_run.display()
        )
    );
    assert!(!g.with_extension("svg").exists() && !g.with_extension("md").exists());
    let e = fails(&[
        "plot",
        "frontier",
        s(&fsrl_run),
        "--pick",
        "common-speed",
        "--list",
    ]);
    assert!(e.contains("cannot be used with"), "{e}");
    let e = fails(&["plot", "frontier", s(&fsrl_run), "--pick", "fastest"]);
    assert!(e.contains("invalid value 'fastest'"), "{e}");

    // Not a run directory: a clear error.
    let e = fails(&["plot", "frontier", s(dir), "--out", s(&dir.join("g"))]);
    assert!(e.contains("not a run directory (no config.toml"), "{e}");
    // A metrics.jsonl alone: with what to assume of it.
    std::fs::remove_file(fsrl_run.join("config.toml")).unwrap();
    let e = fails(&["plot", "frontier", s(&fsrl_run), "--out", s(&dir.join("g"))]);
    assert!(
        e.contains("pass --method, --setting and --decay-end"),
        "{e}"
    );
    let g = dir.join("g");
    let assumed = |extra: &[&str]| {
        let mut args = vec!["plot", "frontier", s(&fsrl_run), "--out", s(&g)];
        args.extend([
            "--method",
            "fsrl",
            "--setting",
            "env1-visible",
            "--decay-end",
            "100",
        ]);
        args.extend(extra);
        ok(&args)
    };
    // --list: the snapshots that take part, and no picture.
    let listed = ok(&["plot", "frontier", s(&sarl_run), "--list", "--out", s(&g)]);
    assert_eq!(
        listed,
        format!("{0}\t100\n{0}\t200\n", sarl_run.display()),
        "{listed}"
    );
    assert!(!g.with_extension("svg").exists() && !g.with_extension("md").exists());
    let stdout = assumed(&[]);
    assert!(stdout.contains("| fsrl | env1-visible | 0 | 2 | 11.00 s / 0.050 (ep 100) | 12.00 s / 0.030 (ep 200) | – |"), "{stdout}");
    // --min-success 0.9 lets the snapshot after 300 episodes (success 0.94) in: the fastest.
    let stdout = assumed(&["--min-success", "0.9"]);
    assert!(
        stdout.contains("| 3 | 10.00 s / 0.010 (ep 300) |"),
        "{stdout}"
    );
    let e = fails(&[
        "plot",
        "frontier",
        s(&sarl_run),
        "--min-success",
        "NaN",
        "--out",
        s(&dir.join("g")),
    ]);
    assert!(e.contains("not a rate in [0, 1]"), "{e}");
    keep(&dir.join("pics"));
}

#[test]
fn bad_inputs_are_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let e = fails(&["eval", s(&dir.join("nope.ckpt")), "--episodes", "1"]);
    assert!(
        e.contains("nope.ckpt: no such checkpoint or run directory"),
        "{e}"
    );
    let e = fails(&["eval", "--episodes", "1"]);
    assert!(e.contains("nothing to evaluate"), "{e}");
    let e = fails(&[
        "eval",
        "--orca",
        "--settings",
        "env9-visible",
        "--episodes",
        "1",
    ]);
    assert!(e.contains("env9-visible"), "{e}");

    let garbage = dir.join("garbage.ckpt");
    std::fs::write(&garbage, b"not a checkpoint").unwrap();
    let e = fails(&["eval", s(&garbage), "--episodes", "1"]);
    assert!(e.contains("garbage.ckpt"), "{e}");

    let run = dir.join("run");
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(
        run.join("metrics.jsonl"),
        "{\"phase\":\"imitation\",\"epoch\":0,\"loss\":0.1,\"wall_s\":0.5}\n{\"phase\":\"rl\",\"episode\":\n",
    )
    .unwrap();
    let e = fails(&["plot", "curves", s(&run), "--out", s(&dir.join("c"))]);
    assert!(e.contains("metrics.jsonl:2: not JSON"), "{e}");

    let e = fails(&["compare", s(&run)]);
    assert!(e.contains("neither eval/eval.json nor report.json"), "{e}");
    let e = fails(&["plot", "episode", "--out", s(&dir.join("e"))]);
    assert!(e.contains("or pass --orca"), "{e}");
}

/// Well-formed files with values no run writes: a report with a success of 1.5 is refused by
/// every reader (compare, the pictures) naming the field; a validation line with a Disc. of −1
/// is skipped with a warning, so it is neither drawn nor the gentlest.
#[test]
fn reports_and_logs_with_impossible_values_are_refused_or_skipped() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let good = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("docs/results/paper-schedule/fsrl-4000x25-env1-invisible-s0.json");
    let mut report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&good).unwrap()).unwrap();
    report["subjects"][0]["settings"][0]["success"] = serde_json::json!(1.5);
    let hostile = dir.join("hostile.json");
    std::fs::write(&hostile, report.to_string()).unwrap();
    for args in [
        vec!["compare", s(&hostile), "--out", s(&dir.join("c"))],
        vec!["plot", "bars", s(&hostile), "--out", s(&dir.join("b"))],
        vec!["plot", "ablation", s(&hostile), "--out", s(&dir.join("a"))],
    ] {
        let e = fails(&args);
        assert!(
            e.contains("hostile.json") && e.contains("success 1.5 is not a fraction in [0, 1]"),
            "{args:?}: {e}"
        );
    }
    assert!(!dir.join("b.svg").exists() && !dir.join("c").exists());

    let run = dir.join("fsrl-env1-invisible-s0");
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(
        run.join("metrics.jsonl"),
        [
            validation_line(2000, 0.97, 100.0) + "\n",
            "{\"phase\":\"validation\",\"episode\":2250,\"success_rate\":1.0,\"collision_rate\":0.0,\"timeout_rate\":0.0,\"discomfort\":-1.0,\"nav_time_s\":11.0}\n".into(),
        ]
        .concat(),
    )
    .unwrap();
    let o = fsrl(&[
        "plot",
        "frontier",
        s(&run),
        "--method",
        "fsrl",
        "--setting",
        "env1-invisible",
        "--decay-end",
        "0",
        "--list",
    ]);
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("1 unreadable or impossible line(s) skipped"),
        "{err}"
    );
    let listed: Vec<&str> = out.lines().filter_map(|l| l.split('\t').nth(1)).collect();
    assert_eq!(listed, ["2000"], "{out}");
}

/// `fsrl compare A... --vs B...` on Experiment 9's committed reports: per-run values, the
/// pooled counts and Welch's test agree with SciPy on the same numbers; an arm of two methods
/// is refused.
#[test]
fn compare_tests_one_arm_against_another() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/results/paper-schedule");
    let arm = |m: &str| -> Vec<String> {
        (0..3)
            .map(|seed| {
                root.join(format!("{m}-4000x25-env1-invisible-s{seed}.json"))
                    .display()
                    .to_string()
            })
            .collect()
    };
    let (fsrl_arm, sarl_arm) = (arm("fsrl"), arm("sarl"));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("vs");
    let mut args: Vec<&str> = vec!["compare"];
    args.extend(fsrl_arm.iter().map(String::as_str));
    args.push("--vs");
    args.extend(sarl_arm.iter().map(String::as_str));
    args.extend(["--out", s(&out)]);
    let table = ok(&args);
    assert!(
        table.contains("- A: fsrl, 3 runs (") && table.contains(&fsrl_arm[2]),
        "{table}"
    );
    assert!(table.contains("- B: sarl, 3 runs ("), "{table}");
    let succ = table
        .lines()
        .find(|l| l.starts_with("| env1-invisible | success |"))
        .unwrap_or_else(|| panic!("no success row:\n{table}"));
    assert!(
        succ.contains("0.966 / 0.954 / 0.978: 0.966 ± 0.012") && succ.contains("pooled 1449/1500"),
        "{succ}"
    );
    assert!(succ.contains("pooled 1444/1500"), "{succ}");
    // SciPy: ttest_ind([0.966, 0.954, 0.978], [0.958, 0.954, 0.976], equal_var=False) gives
    // t = 0.3442, df = 3.998, p = 0.748.
    assert!(succ.ends_with("| +0.003 | 0.34 | 4.0 | 0.748 |"), "{succ}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("compare.json")).unwrap()).unwrap();
    let arms = json["arms"].as_array().unwrap();
    assert_eq!(arms.len(), 5, "one setting × five metrics");
    let disc = arms.iter().find(|t| t["metric"] == "disc").unwrap();
    // SciPy on the reports' Disc. values: t = -0.16553, p = 0.87656.
    let p = disc["welch"]["p"].as_f64().unwrap();
    assert!((p - 0.87656).abs() < 1e-4, "{disc}");
    assert_eq!(disc["a"]["values"].as_array().unwrap().len(), 3);

    // An arm mixing two methods says so.
    let mut mixed: Vec<&str> = vec!["compare", &fsrl_arm[0], &sarl_arm[0], "--vs"];
    mixed.extend(sarl_arm.iter().map(String::as_str));
    let e = fails(&mixed);
    assert!(
        e.contains("arm A holds several methods (sarl, fsrl)"),
        "{e}"
    );
}

/// A report command whose reader has gone (`fsrl compare ... | head -0`) ends by SIGPIPE, as Unix
/// tools do, without a panic.
#[test]
fn a_closed_output_ends_a_report_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let report = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("docs/results/paper-schedule/fsrl-4000x25-env1-invisible-s0.json");
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .arg("compare")
        .arg(&report)
        .stdout(writer)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(
        o.status.signal(),
        Some(libc::SIGPIPE),
        "{:?} {stderr}",
        o.status
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
}
