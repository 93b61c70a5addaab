//! The floor plan of the library (issue 33, CONTRIBUTING.md "Floors"): every top-level module of
//! `src/` sits on a floor, and no code imports from a module on a higher floor. Modules on one
//! floor may use each other, but never in a circle. Read from the source: every `crate::NAME`
//! outside a comment line is an arrow to `NAME`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The floors, lowest first. A new top-level module must be added here (the test says so).
const FLOORS: &[&[&str]] = &[
    // 0: the error type.
    &["error"],
    // 1: utilities every kernel may use.
    &["runtime", "util", "memory", "testing", "progress", "io"],
    // 2: cameras and poses, images, plots.
    &["geometry", "image", "plot"],
    // 3: the kernels (network ops, cost volume, DTAM, dense SIFT, fusion), the data (sequence
    //    readers and writers, the renderer, the metrics) and the performance probes.
    &["ops", "costvolume", "dtam", "dsift", "fusion", "sequence", "eval", "synth", "perf"],
    // 4: the seam.
    &["backend"],
    // 5: the models above the seam.
    &["nn", "normals_net"],
    // 6: the mapper.
    &["mapping"],
    // 7: the trainer.
    &["train"],
];

fn floor_of(module: &str) -> Option<usize> {
    FLOORS.iter().position(|f| f.contains(&module))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// `module -> {imported module -> first file:line}` over the library's code lines.
fn import_graph() -> BTreeMap<String, BTreeMap<String, String>> {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut graph: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    for file in files {
        let rel = file.strip_prefix(&src).unwrap().to_string_lossy().replace('\\', "/");
        let top = rel.split('/').next().unwrap().trim_end_matches(".rs").to_string();
        // The binary's own modules and the crate root are above every floor.
        if matches!(top.as_str(), "main" | "lib" | "cli") {
            continue;
        }
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, line) in text.lines().enumerate() {
            if line.trim_start().starts_with("//") {
                continue;
            }
            for (i, _) in line.match_indices("crate::") {
                // Not `densefeat_crate::` or the like: `crate` starts a path.
                if i > 0 && line[..i].ends_with(|c: char| c.is_alphanumeric() || c == '_') {
                    continue;
                }
                let name: String =
                    line[i + 7..].chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
                if !name.is_empty() && name != top && name.chars().next().unwrap().is_lowercase() {
                    graph
                        .entry(top.clone())
                        .or_default()
                        .entry(name)
                        .or_insert(format!("src/{rel}:{}", n + 1));
                }
            }
        }
        graph.entry(top).or_default();
    }
    graph
}

#[test]
fn no_module_imports_from_a_higher_floor() {
    let graph = import_graph();
    let mut problems = Vec::new();
    for (module, imports) in &graph {
        let Some(f) = floor_of(module) else {
            problems.push(format!(
                "src/{module}: a top-level module on no floor; add it to FLOORS in tests/layering.rs"
            ));
            continue;
        };
        for (target, at) in imports {
            match floor_of(target) {
                Some(g) if g <= f => {}
                Some(g) => {
                    problems.push(format!("{at}: {module} (floor {f}) imports {target} (floor {g}, higher)"))
                }
                None => problems.push(format!("{at}: {module} imports {target}, which is on no floor")),
            }
        }
    }
    assert!(problems.is_empty(), "the floor plan is broken:\n{}", problems.join("\n"));
}

#[test]
fn modules_on_one_floor_import_each_other_in_no_circle() {
    let graph = import_graph();
    // Depth-first search for a back edge.
    fn visit<'a>(
        m: &'a str,
        graph: &'a BTreeMap<String, BTreeMap<String, String>>,
        state: &mut BTreeMap<&'a str, u8>,
        path: &mut Vec<&'a str>,
    ) -> Option<Vec<String>> {
        state.insert(m, 1);
        path.push(m);
        for next in graph.get(m).map(|i| i.keys()).into_iter().flatten() {
            match state.get(next.as_str()) {
                Some(1) => {
                    let start = path.iter().position(|p| p == next).unwrap();
                    let mut cycle: Vec<String> = path[start..].iter().map(|s| s.to_string()).collect();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                Some(_) => {}
                None => {
                    if let Some(c) = visit(next, graph, state, path) {
                        return Some(c);
                    }
                }
            }
        }
        path.pop();
        state.insert(m, 2);
        None
    }
    let mut state = BTreeMap::new();
    for m in graph.keys() {
        if !state.contains_key(m.as_str()) {
            if let Some(cycle) = visit(m, &graph, &mut state, &mut Vec::new()) {
                panic!("modules import each other in a circle: {}", cycle.join(" -> "));
            }
        }
    }
    // Every floor's modules exist (a renamed module must be renamed here too).
    let present: BTreeSet<&str> = graph.keys().map(String::as_str).collect();
    for m in FLOORS.iter().flat_map(|f| f.iter()) {
        assert!(present.contains(m), "FLOORS lists {m}, which is not a module of src/");
    }
}
