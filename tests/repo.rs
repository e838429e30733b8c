//! The repository's shape: the module graph of `src/` has no cycle, files stay readable in size,
//! `main.rs` only parses and dispatches, the README stays a guide, and every relative link or
//! image in the README and `docs/` points at a file (and heading) that exists.
//!
//! The module graph is read from the sources: a file `src/a/b.rs` (or `src/a/b/mod.rs`) is module
//! `a::b`; a path `crate::a::b::X` or `super::X` anywhere in it (comments left out; an inline
//! `#[cfg(test)] mod tests` is scanned too) is an edge to the longest module prefix of that path. Edges to a module's own
//! ancestors or descendants (re-exports through `mod.rs`) are not dependencies between siblings
//! and are left out; the CLI (`src/cli/`, the binary's) is checked apart from the library.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else { return };
    let mut entries: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

type Module = Vec<String>;

fn module_of(src: &Path, file: &Path) -> Module {
    let rel = file.strip_prefix(src).expect("file under src");
    let mut parts: Vec<String> = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
    if let Some(last) = parts.last_mut() {
        *last = last.trim_end_matches(".rs").to_string();
    }
    if parts.last().is_some_and(|l| l == "mod") {
        parts.pop();
    }
    if parts.len() == 1 && (parts[0] == "lib" || parts[0] == "main") {
        parts.clear();
    }
    parts
}

/// The source without line comments, split where an inline `#[cfg(test)] mod … {` begins: the
/// file's own code, and the unit-test module (whose `super::` is the file's module itself). The
/// whole file is scanned: a test module's imports are dependencies too.
fn code_of(text: &str) -> (String, String) {
    let strip = |t: &str| {
        t.lines()
            .map(|l| match l.find("//") {
                Some(i) => &l[..i],
                None => l,
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    let cut = text
        .match_indices("#[cfg(test)]\nmod ")
        .map(|(i, _)| i)
        .find(|&i| {
            text[i..]
                .lines()
                .nth(1)
                .is_some_and(|l| l.trim_end().ends_with('{'))
        })
        .unwrap_or(text.len());
    (strip(&text[..cut]), strip(&text[cut..]))
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Every `crate::a::b…` / `super::a…` path in the code, expanded through `use …::{x, y::z}`
/// groups, as (head, segments).
fn paths_in(code: &str) -> Vec<(String, Vec<String>)> {
    let mut out = Vec::new();
    let chars: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let rest: String = chars[i..chars.len().min(i + 8)].iter().collect();
        let head = if rest.starts_with("crate::") {
            "crate"
        } else if rest.starts_with("super::") {
            "super"
        } else {
            i += 1;
            continue;
        };
        if i > 0 && is_ident(chars[i - 1]) {
            i += 1;
            continue;
        }
        i += head.len();
        let mut segs = Vec::new();
        while i + 1 < chars.len() && chars[i] == ':' && chars[i + 1] == ':' {
            i += 2;
            if chars.get(i) == Some(&'{') {
                // A use group: split its top-level items.
                let mut depth = 0;
                let start = i + 1;
                let mut end = start;
                for (k, &c) in chars.iter().enumerate().skip(i) {
                    if c == '{' {
                        depth += 1;
                    } else if c == '}' {
                        depth -= 1;
                        if depth == 0 {
                            end = k;
                            break;
                        }
                    }
                }
                let group: String = chars[start..end].iter().collect();
                let mut depth = 0;
                let mut item = String::new();
                let mut items = Vec::new();
                for c in group.chars() {
                    match c {
                        '{' => depth += 1,
                        '}' => depth -= 1,
                        ',' if depth == 0 => {
                            items.push(std::mem::take(&mut item));
                            continue;
                        }
                        _ => {}
                    }
                    item.push(c);
                }
                items.push(item);
                for it in items {
                    let it: String = it.chars().take_while(|&c| c != '{').collect();
                    let it = it.split(" as ").next().unwrap_or("").trim().to_string();
                    if it.is_empty() || it == "self" {
                        continue;
                    }
                    let mut s = segs.clone();
                    s.extend(
                        it.split("::")
                            .map(|x| x.trim().to_string())
                            .filter(|x| !x.is_empty()),
                    );
                    out.push((head.to_string(), s));
                }
                i = end;
                segs.clear();
                break;
            }
            let start = i;
            while i < chars.len() && is_ident(chars[i]) {
                i += 1;
            }
            if i == start {
                break;
            }
            segs.push(chars[start..i].iter().collect());
        }
        if !segs.is_empty() {
            out.push((head.to_string(), segs));
        }
    }
    out
}

/// The module graph of the files under `src` (a subtree, `skip` left out).
fn module_graph(src: &Path, skip: &[&str]) -> BTreeMap<Module, BTreeSet<Module>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut modules: BTreeMap<Module, String> = BTreeMap::new();
    for f in files {
        let m = module_of(src, &f);
        if m.first().is_some_and(|h| skip.contains(&h.as_str())) {
            continue;
        }
        modules.insert(m, fs::read_to_string(&f).expect("read source"));
    }
    let resolve = |path: &[String]| -> Option<Module> {
        (1..=path.len())
            .rev()
            .map(|n| path[..n].to_vec())
            .find(|p| modules.contains_key(p))
    };
    let is_prefix = |a: &Module, b: &Module| a.len() < b.len() && b[..a.len()] == a[..];
    let mut graph = BTreeMap::new();
    for (m, text) in &modules {
        let mut deps = BTreeSet::new();
        let (code, tests) = code_of(text);
        let scanned = paths_in(&code)
            .into_iter()
            .map(|p| (p, m.len().saturating_sub(1)))
            .chain(paths_in(&tests).into_iter().map(|p| (p, m.len())));
        for ((head, segs), base) in scanned {
            let full: Vec<String> = if head == "crate" {
                segs
            } else {
                m[..base].iter().cloned().chain(segs).collect()
            };
            if let Some(t) = resolve(&full) {
                if &t != m && !is_prefix(&t, m) && !is_prefix(m, &t) {
                    deps.insert(t);
                }
            }
        }
        graph.insert(m.clone(), deps);
    }
    graph
}

/// The strongly connected components with more than one module (Tarjan).
fn cycles(graph: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<Vec<Module>> {
    struct State<'a> {
        graph: &'a BTreeMap<Module, BTreeSet<Module>>,
        index: BTreeMap<&'a Module, usize>,
        low: BTreeMap<&'a Module, usize>,
        stack: Vec<&'a Module>,
        on: BTreeSet<&'a Module>,
        next: usize,
        out: Vec<Vec<Module>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a Module) {
        s.index.insert(v, s.next);
        s.low.insert(v, s.next);
        s.next += 1;
        s.stack.push(v);
        s.on.insert(v);
        let graph = s.graph;
        for w in graph.get(v).into_iter().flatten() {
            let Some((w, _)) = graph.get_key_value(w) else {
                continue;
            };
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low[v];
                s.low.insert(v, lv.min(lw));
            } else if s.on.contains(w) {
                let iw = s.index[w];
                let lv = s.low[v];
                s.low.insert(v, lv.min(iw));
            }
        }
        if s.low[v] == s.index[v] {
            let mut comp = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on.remove(w);
                comp.push(w.clone());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                s.out.push(comp);
            }
        }
    }
    let mut s = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in graph.keys() {
        if !s.index.contains_key(v) {
            visit(&mut s, v);
        }
    }
    s.out
}

fn describe(graph: &BTreeMap<Module, BTreeSet<Module>>, comp: &[Module]) -> String {
    comp.iter()
        .map(|m| {
            let deps: Vec<String> = graph[m]
                .iter()
                .filter(|d| comp.contains(d))
                .map(|d| d.join("::"))
                .collect();
            format!("{} -> {}", m.join("::"), deps.join(", "))
        })
        .collect::<Vec<_>>()
        .join("; ")
}

#[test]
fn the_module_graph_has_no_cycle() {
    let src = root().join("src");
    for (what, graph) in [
        ("library", module_graph(&src, &["cli"])),
        ("CLI", module_graph(&src.join("cli"), &[])),
    ] {
        let found = cycles(&graph);
        let text: Vec<String> = found.iter().map(|c| describe(&graph, c)).collect();
        assert!(
            found.is_empty(),
            "import cycles in the {what}: {}",
            text.join(" | ")
        );
        // The top-level modules too (detect -> eval -> detect would be a cycle of subtrees).
        let mut top: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
        for (m, deps) in &graph {
            let Some(h) = m.first() else { continue };
            let entry = top.entry(vec![h.clone()]).or_default();
            for d in deps {
                if let Some(dh) = d.first().filter(|dh| *dh != h) {
                    entry.insert(vec![dh.clone()]);
                }
            }
        }
        let found = cycles(&top);
        let text: Vec<String> = found.iter().map(|c| describe(&top, c)).collect();
        assert!(
            found.is_empty(),
            "cycles between the {what}'s top-level modules: {}",
            text.join(" | ")
        );
    }
}

/// The window's modules (`gui`, `render`: the ones `src/lib.rs` builds only with the `gui`
/// feature) are leaves: no other library module imports them. So the library without the feature
/// (the Python wheel's) is the same code as with it, less those two, and CI may test the Python
/// package against the library built with its default features.
#[test]
fn no_library_module_imports_the_window() {
    let src = root().join("src");
    let lib = fs::read_to_string(src.join("lib.rs")).expect("read src/lib.rs");
    let gated: Vec<String> = lib
        .split("#[cfg(feature = \"gui\")]")
        .skip(1)
        .filter_map(|rest| {
            let line = rest.trim_start().lines().next()?;
            line.strip_prefix("pub mod ")
                .map(|m| m.trim_end_matches(';').to_string())
        })
        .collect();
    assert_eq!(gated, ["gui", "render"], "src/lib.rs's gui-gated modules");
    let graph = module_graph(&src, &["cli"]);
    let offenders: Vec<String> = graph
        .iter()
        .filter(|(m, _)| m.first().is_none_or(|h| !gated.contains(h)))
        .flat_map(|(m, deps)| {
            deps.iter()
                .filter(|d| d.first().is_some_and(|h| gated.contains(h)))
                .map(move |d| format!("{} -> {}", m.join("::"), d.join("::")))
        })
        .collect();
    assert!(
        offenders.is_empty(),
        "library modules import the window's: {}",
        offenders.join(", ")
    );
}

#[test]
fn the_cycle_finder_finds_a_cycle() {
    // a -> b -> c -> a through `use` groups and a `super::` path; d only depends on them.
    let dir = std::env::temp_dir().join(format!("mlod-repo-cycles-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(dir.join("m")).unwrap();
    fs::write(dir.join("lib.rs"), "pub mod m;\npub mod d;\n").unwrap();
    fs::write(
        dir.join("m/mod.rs"),
        "pub mod a;\npub mod b;\npub mod c;\npub use a::A;\n",
    )
    .unwrap();
    fs::write(
        dir.join("m/a.rs"),
        "use crate::m::{b::{B, Bee}, c as _};\npub struct A;\n",
    )
    .unwrap();
    fs::write(
        dir.join("m/b.rs"),
        "// use super::a::A;\npub struct B(super::c::C);\npub struct Bee;\n",
    )
    .unwrap();
    fs::write(
        dir.join("m/c.rs"),
        "pub struct C(crate::m::a::A);\n#[cfg(test)]\nmod tests {\n    use super::C;\n    use crate::d::D;\n}\n",
    )
    .unwrap();
    fs::write(dir.join("d.rs"), "pub struct D(crate::m::A);\n").unwrap();
    let graph = module_graph(&dir, &[]);
    let found = cycles(&graph);
    let _ = fs::remove_dir_all(&dir);
    assert_eq!(found.len(), 1, "{graph:?}");
    let mut comp: Vec<String> = found[0].iter().map(|m| m.join("::")).collect();
    comp.sort();
    assert_eq!(comp, ["m::a", "m::b", "m::c"]);
    // The commented-out use is not an edge; the test module's use is, and its `super::` is c.
    let m = |p: &str| p.split("::").map(String::from).collect::<Vec<_>>();
    assert!(!graph[&m("m::b")].contains(&m("m::a")));
    assert_eq!(graph[&m("m::c")], [m("m::a"), m("d")].into_iter().collect());
}

fn line_count(p: &Path) -> usize {
    fs::read_to_string(p).map(|t| t.lines().count()).unwrap_or(0)
}

#[test]
fn files_stay_readable_and_main_only_dispatches() {
    // Source and test files alike.
    let mut files = Vec::new();
    rust_files(&root().join("src"), &mut files);
    rust_files(&root().join("tests"), &mut files);
    let long: Vec<String> = files
        .iter()
        .filter(|f| line_count(f) > 850)
        .map(|f| format!("{} ({} lines)", f.display(), line_count(f)))
        .collect();
    assert!(long.is_empty(), "files over ~800 lines: {long:?}");
    let main = line_count(&root().join("src/main.rs"));
    assert!(
        main <= 150,
        "src/main.rs has {main} lines: it should only parse and dispatch"
    );
    let readme = line_count(&root().join("README.md"));
    assert!(
        readme <= 300,
        "README.md has {readme} lines: move write-ups to docs/"
    );
}

/// The lines of Rust under `dir` (or in `dir.rs`).
fn lines_under(path: &Path) -> usize {
    let mut files = Vec::new();
    if path.is_dir() {
        rust_files(path, &mut files);
    }
    let file = path.with_extension("rs");
    if file.is_file() {
        files.push(file);
    }
    files.iter().map(|f| line_count(f)).sum()
}

/// The top-level modules of the library and the binary: each folder or file under `src/`.
fn top_level_modules() -> Vec<String> {
    let mut names: BTreeSet<String> = BTreeSet::new();
    for e in fs::read_dir(root().join("src")).expect("src/").flatten() {
        let p = e.path();
        let name = p
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if (p.is_dir() || p.extension().is_some_and(|x| x == "rs"))
            && !["lib", "main"].contains(&name.as_str())
        {
            names.insert(name);
        }
    }
    names.into_iter().collect()
}

#[test]
fn no_top_level_module_holds_more_than_fifteen_percent_of_the_code() {
    let total = lines_under(&root().join("src"));
    let sizes: Vec<(String, usize)> = top_level_modules()
        .into_iter()
        .map(|m| {
            let n = lines_under(&root().join("src").join(&m));
            (m, n)
        })
        .collect();
    assert!(sizes.len() >= 10 && total > 10_000, "{sizes:?}");
    let big: Vec<String> = sizes
        .iter()
        .filter(|(_, n)| *n * 100 > total * 15)
        .map(|(m, n)| {
            format!(
                "{m}/ ({n} of {total} lines, {:.1} %)",
                100.0 * *n as f64 / total as f64
            )
        })
        .collect();
    assert!(big.is_empty(), "split these: {big:?}");
}

#[test]
fn the_architecture_map_names_every_module_and_the_licences_are_there() {
    let map = fs::read_to_string(root().join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let missing: Vec<String> = top_level_modules()
        .into_iter()
        .filter(|m| !map.contains(&format!("`{m}/`")) && !map.contains(&format!("`{m}.rs`")))
        .collect();
    assert!(missing.is_empty(), "ARCHITECTURE.md does not name {missing:?}");
    for f in ["LICENSE-MIT", "LICENSE-APACHE"] {
        let text = fs::read_to_string(root().join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        assert!(text.len() > 900, "{f} is not a licence text");
    }
}

/// GitHub's heading anchor: lowercase, spaces to '-', other punctuation dropped.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

fn anchors(markdown: &str) -> BTreeSet<String> {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut out = BTreeSet::new();
    let mut fenced = false;
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced || !line.starts_with('#') {
            continue;
        }
        let text = line.trim_start_matches('#');
        // Inline code and emphasis marks are not part of the anchor text.
        let base = slug(&text.replace(['`', '*'], ""));
        let n = seen.entry(base.clone()).or_insert(0);
        out.insert(if *n == 0 {
            base.clone()
        } else {
            format!("{base}-{n}")
        });
        *n += 1;
    }
    out
}

/// Every `[text](target)` / `![alt](target)` outside code blocks and inline code.
fn links(markdown: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut fenced = false;
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        // Drop inline code spans.
        let mut clean = String::new();
        let mut in_code = false;
        for c in line.chars() {
            if c == '`' {
                in_code = !in_code;
            } else if !in_code {
                clean.push(c);
            }
        }
        let mut rest = clean.as_str();
        while let Some(i) = rest.find("](") {
            let after = &rest[i + 2..];
            let Some(end) = after.find(')') else { break };
            out.push(after[..end].split_whitespace().next().unwrap_or("").to_string());
            rest = &after[end..];
        }
    }
    out
}

#[test]
fn relative_links_in_the_readme_and_docs_resolve() {
    let root = root();
    let mut pages = vec![root.join("README.md")];
    if let Ok(entries) = fs::read_dir(root.join("docs")) {
        let mut docs: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "md"))
            .collect();
        docs.sort();
        pages.extend(docs);
    }
    let mut broken = Vec::new();
    let mut checked = 0;
    for page in &pages {
        let text = fs::read_to_string(page).expect("read page");
        for link in links(&text) {
            if link.is_empty() || link.contains("://") || link.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            let (path, anchor) = match link.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (link.as_str(), None),
            };
            let target = if path.is_empty() {
                page.clone()
            } else {
                page.parent().unwrap_or(&root).join(path)
            };
            if !target.exists() {
                broken.push(format!("{}: {link} (no such file)", page.display()));
                continue;
            }
            if let Some(a) = anchor {
                let md = fs::read_to_string(&target).unwrap_or_default();
                if target.extension().is_some_and(|e| e == "md") && !anchors(&md).contains(a) {
                    broken.push(format!("{}: {link} (no heading #{a})", page.display()));
                }
            }
        }
    }
    assert!(checked > 0, "no relative links found at all");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn the_link_checker_sees_links_and_anchors() {
    let md = "# Top\n## Why plain NMS tied (v2)\n```\n[not](a link)\n```\nsee [x](docs/a.md#why) and ![i](s.png) but not `[c](d)`\n";
    assert_eq!(links(md), ["docs/a.md#why", "s.png"]);
    let a = anchors(md);
    assert!(a.contains("top") && a.contains("why-plain-nms-tied-v2"), "{a:?}");
}

/// Every "command" string in a JSON value, with its key path.
fn commands_in(v: &serde_json::Value, path: &str, out: &mut Vec<(String, String)>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                let p = format!("{path}/{k}");
                match x {
                    serde_json::Value::String(s) if k.ends_with("command") && !s.is_empty() => {
                        out.push((p, s.clone()))
                    }
                    _ => commands_in(x, &p, out),
                }
            }
        }
        serde_json::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                commands_in(x, &format!("{path}/{i}"), out);
            }
        }
        _ => {}
    }
}

#[test]
fn model_provenance_names_the_command_a_user_types() {
    let mut manifests = Vec::new();
    let dir = root().join("assets/models");
    manifests.push(dir.join("manifest.json"));
    for e in fs::read_dir(&dir).unwrap().flatten() {
        if e.path().join("manifest.json").is_file() {
            manifests.push(e.path().join("manifest.json"));
        }
    }
    let mut seen = 0;
    for m in manifests {
        let v: serde_json::Value = serde_json::from_str(&fs::read_to_string(&m).unwrap()).unwrap();
        let mut cmds = Vec::new();
        commands_in(&v, "", &mut cmds);
        for (path, c) in cmds {
            seen += 1;
            assert!(
                c.starts_with("mlod "),
                "{}{path}: the command is `{c}`; provenance names the command as a user types it (`mlod …`)",
                m.display()
            );
            // Paths as a user types them: relative, never one machine's folders.
            for arg in c.split_whitespace() {
                let value = arg.split_once('=').map_or(arg, |(_, v)| v);
                assert!(
                    !value.starts_with('/') && !value.starts_with('~') && !value.contains(":\\"),
                    "{}{path}: `{c}` holds the absolute path {value}",
                    m.display()
                );
            }
        }
    }
    assert!(seen >= 10, "only {seen} commands found in the manifests");
}
