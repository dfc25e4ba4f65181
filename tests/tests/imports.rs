//! No import cycle between the source files of `ess-envs` and `ess-learner` (issue 41):
//! a file may use what files below it define, never what uses it back, so each part
//! can be read, tested and replaced from the bottom up.
//!
//! The check parses every file of a crate with `syn` (test code, `#[cfg(test)]`, left
//! out), following the module tree from the crate root's `mod` declarations. Each path
//! that starts at `crate`, `super` or `self` (in `use` declarations and in code) is an
//! edge to the file that *defines* what it names: a name re-exported by a `pub use`
//! (in `lib.rs` or a `mod.rs`) is followed to the file that defines it, so a facade
//! module is not an edge of its own. Then the strongly connected components of the
//! graph must all be single files.
//!
//! The same graph checks one layering rule of the design: the training core does not
//! import the logs that sit above it (issue 41).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use syn::visit::Visit;

/// A module path from the crate root (`[]` is the root).
type ModPath = Vec<String>;

/// What one file holds, as far as the check needs it.
#[derive(Default)]
struct FileInfo {
    path: PathBuf,
    /// Names the file defines (types, functions, traits, constants, inline modules).
    defines: BTreeSet<String>,
    /// `pub use` names: alias -> absolute path.
    reexports: BTreeMap<String, ModPath>,
    /// `pub use m::*` targets.
    globs: Vec<ModPath>,
    /// Absolute paths the file's (non-test) code refers to.
    refs: Vec<ModPath>,
}

fn is_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| match &a.meta {
        syn::Meta::List(l) if l.path.is_ident("cfg") => {
            let t = l.tokens.to_string();
            t.contains("test") && !t.contains("not")
        }
        _ => false,
    })
}

fn item_attrs(item: &syn::Item) -> &[syn::Attribute] {
    use syn::Item::*;
    match item {
        Const(i) => &i.attrs,
        Enum(i) => &i.attrs,
        ExternCrate(i) => &i.attrs,
        Fn(i) => &i.attrs,
        ForeignMod(i) => &i.attrs,
        Impl(i) => &i.attrs,
        Macro(i) => &i.attrs,
        Mod(i) => &i.attrs,
        Static(i) => &i.attrs,
        Struct(i) => &i.attrs,
        Trait(i) => &i.attrs,
        TraitAlias(i) => &i.attrs,
        Type(i) => &i.attrs,
        Union(i) => &i.attrs,
        Use(i) => &i.attrs,
        _ => &[],
    }
}

fn item_name(item: &syn::Item) -> Option<String> {
    use syn::Item::*;
    let id = match item {
        Const(i) => &i.ident,
        Enum(i) => &i.ident,
        Fn(i) => &i.sig.ident,
        Mod(i) => &i.ident,
        Static(i) => &i.ident,
        Struct(i) => &i.ident,
        Trait(i) => &i.ident,
        Type(i) => &i.ident,
        Union(i) => &i.ident,
        Macro(i) => i.ident.as_ref()?,
        _ => return None,
    };
    Some(id.to_string())
}

/// `use` trees flattened to `(path, alias)`; a glob has alias `*`.
fn flatten(tree: &syn::UseTree, prefix: &mut ModPath, out: &mut Vec<(ModPath, String)>) {
    match tree {
        syn::UseTree::Path(p) => {
            prefix.push(p.ident.to_string());
            flatten(&p.tree, prefix, out);
            prefix.pop();
        }
        syn::UseTree::Name(n) => {
            let name = n.ident.to_string();
            let mut p = prefix.clone();
            if name != "self" {
                p.push(name.clone());
            }
            let alias = if name == "self" {
                prefix.last().cloned().unwrap_or_default()
            } else {
                name
            };
            out.push((p, alias));
        }
        syn::UseTree::Rename(r) => {
            let mut p = prefix.clone();
            if r.ident != "self" {
                p.push(r.ident.to_string());
            }
            out.push((p, r.rename.to_string()));
        }
        syn::UseTree::Glob(_) => out.push((prefix.clone(), "*".into())),
        syn::UseTree::Group(g) => {
            for t in &g.items {
                flatten(t, prefix, out);
            }
        }
    }
}

/// A path relative to module `here` made absolute, if it starts at `crate`, `super`,
/// `self` or one of `here`'s own modules (`children`: the names its `mod` items
/// declare); other paths (other crates, local names) are not edges.
fn absolute(here: &[String], children: &BTreeSet<String>, segs: &[String]) -> Option<ModPath> {
    let first = segs.first()?.as_str();
    let mut base: ModPath = match first {
        "crate" => Vec::new(),
        "self" | "super" => here.to_vec(),
        _ if children.contains(first) => {
            let mut p = here.to_vec();
            p.extend(segs.iter().cloned());
            return Some(p);
        }
        _ => return None,
    };
    let mut rest = &segs[1..];
    if first == "super" {
        base.pop()?;
    }
    while rest.first().map(String::as_str) == Some("super") {
        base.pop()?;
        rest = &rest[1..];
    }
    base.extend(rest.iter().cloned());
    Some(base)
}

/// The names of the (non-test) modules that `items` declare.
fn child_modules(items: &[syn::Item]) -> BTreeSet<String> {
    items
        .iter()
        .filter_map(|i| match i {
            syn::Item::Mod(m) if !is_test(&m.attrs) => Some(m.ident.to_string()),
            _ => None,
        })
        .collect()
}

struct Collector<'a> {
    here: ModPath,
    /// The modules declared in the scope being visited, one set per open scope.
    children: Vec<BTreeSet<String>>,
    info: &'a mut FileInfo,
    /// Inline (non-test) modules: their own paths.
    inline: Vec<ModPath>,
}

impl<'ast> Visit<'ast> for Collector<'_> {
    fn visit_item(&mut self, item: &'ast syn::Item) {
        if is_test(item_attrs(item)) {
            return;
        }
        if self.here.len() == self.depth_of_file()
            && let Some(name) = item_name(item)
        {
            self.info.defines.insert(name);
        }
        match item {
            syn::Item::Use(u) => {
                let mut flat = Vec::new();
                flatten(&u.tree, &mut Vec::new(), &mut flat);
                let public = !matches!(u.vis, syn::Visibility::Inherited);
                for (p, alias) in flat {
                    let Some(abs) = absolute(&self.here, self.scope(), &p) else {
                        continue;
                    };
                    // A re-export is followed by who names it, not an edge itself.
                    if public && self.here.len() == self.depth_of_file() {
                        if alias == "*" {
                            self.info.globs.push(abs);
                        } else {
                            self.info.reexports.insert(alias, abs);
                        }
                    } else {
                        self.info.refs.push(abs);
                    }
                }
            }
            syn::Item::Mod(m) if m.content.is_some() => {
                self.here.push(m.ident.to_string());
                self.inline.push(self.here.clone());
                let items = m.content.as_ref().map_or(&[][..], |(_, i)| &i[..]);
                self.children.push(child_modules(items));
                syn::visit::visit_item_mod(self, m);
                self.children.pop();
                self.inline.pop();
                self.here.pop();
            }
            _ => syn::visit::visit_item(self, item),
        }
    }

    fn visit_impl_item_fn(&mut self, f: &'ast syn::ImplItemFn) {
        if !is_test(&f.attrs) {
            syn::visit::visit_impl_item_fn(self, f);
        }
    }

    fn visit_path(&mut self, p: &'ast syn::Path) {
        let segs: ModPath = p.segments.iter().map(|s| s.ident.to_string()).collect();
        if segs.len() >= 2
            && let Some(abs) = absolute(&self.here, self.scope(), &segs)
        {
            self.info.refs.push(abs);
        }
        syn::visit::visit_path(self, p);
    }
}

impl Collector<'_> {
    fn scope(&self) -> &BTreeSet<String> {
        static EMPTY: BTreeSet<String> = BTreeSet::new();
        self.children.last().unwrap_or(&EMPTY)
    }

    fn depth_of_file(&self) -> usize {
        self.here.len() - self.inline.len()
    }
}

/// Every file of the module tree under `root` (a crate root file), by module path.
fn module_tree(root: &Path) -> BTreeMap<ModPath, FileInfo> {
    let mut files = BTreeMap::new();
    let mut todo = vec![(Vec::<String>::new(), root.to_path_buf())];
    while let Some((module, path)) = todo.pop() {
        let src = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
        let ast = syn::parse_file(&src).unwrap_or_else(|e| panic!("{path:?}: {e}"));
        // Child files: `mod x;` next to a `lib.rs`/`main.rs`/`mod.rs`, else in a
        // folder named after this file.
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
        let dir = match stem {
            "lib" | "main" | "mod" => path.parent().map(Path::to_path_buf),
            _ => path.parent().map(|p| p.join(stem)),
        }
        .expect("a file has a folder");
        for item in &ast.items {
            if let syn::Item::Mod(m) = item
                && m.content.is_none()
                && !is_test(&m.attrs)
            {
                let name = m.ident.to_string();
                let flat = dir.join(format!("{name}.rs"));
                let child = if flat.exists() {
                    flat
                } else {
                    dir.join(&name).join("mod.rs")
                };
                let mut p = module.clone();
                p.push(name);
                todo.push((p, child));
            }
        }
        let mut info = FileInfo {
            path: path.clone(),
            ..FileInfo::default()
        };
        let mut c = Collector {
            here: module.clone(),
            children: vec![child_modules(&ast.items)],
            info: &mut info,
            inline: Vec::new(),
        };
        for item in &ast.items {
            c.visit_item(item);
        }
        files.insert(module, info);
    }
    files
}

/// The file that defines what `path` names, following `pub use` re-exports.
fn defining_file(files: &BTreeMap<ModPath, FileInfo>, path: &[String], depth: u32) -> ModPath {
    let k = (0..=path.len())
        .rev()
        .find(|&k| files.contains_key(&path[..k]))
        .unwrap_or(0);
    let module = path[..k].to_vec();
    let (Some(name), Some(info)) = (path.get(k), files.get(&module)) else {
        return module;
    };
    if depth > 8 || info.defines.contains(name) {
        return module;
    }
    if let Some(target) = info.reexports.get(name) {
        let mut t = target.clone();
        t.extend(path[k + 1..].iter().cloned());
        return defining_file(files, &t, depth + 1);
    }
    for g in &info.globs {
        let mut t = g.clone();
        t.extend(path[k..].iter().cloned());
        let f = defining_file(files, &t, depth + 1);
        if files
            .get(&f)
            .is_some_and(|i| i.defines.contains(name) || i.reexports.contains_key(name))
        {
            return f;
        }
    }
    module
}

/// Strongly connected components of more than one file (Tarjan's algorithm).
fn cycles(edges: &BTreeMap<ModPath, BTreeSet<ModPath>>) -> Vec<Vec<ModPath>> {
    struct T<'a> {
        edges: &'a BTreeMap<ModPath, BTreeSet<ModPath>>,
        index: BTreeMap<&'a ModPath, usize>,
        low: BTreeMap<&'a ModPath, usize>,
        stack: Vec<&'a ModPath>,
        on: BTreeSet<&'a ModPath>,
        out: Vec<Vec<ModPath>>,
    }
    impl<'a> T<'a> {
        fn visit(&mut self, v: &'a ModPath) {
            let i = self.index.len();
            self.index.insert(v, i);
            self.low.insert(v, i);
            self.stack.push(v);
            self.on.insert(v);
            for w in self.edges.get(v).into_iter().flatten() {
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let lw = self.low[w];
                    let lv = self.low.get_mut(v).expect("visited");
                    *lv = (*lv).min(lw);
                } else if self.on.contains(w) {
                    let iw = self.index[w];
                    let lv = self.low.get_mut(v).expect("visited");
                    *lv = (*lv).min(iw);
                }
            }
            if self.low[v] == self.index[v] {
                let mut comp = Vec::new();
                while let Some(w) = self.stack.pop() {
                    self.on.remove(w);
                    comp.push(w.clone());
                    if w == v {
                        break;
                    }
                }
                if comp.len() > 1 {
                    self.out.push(comp);
                }
            }
        }
    }
    let mut t = T {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in edges.keys() {
        if !t.index.contains_key(v) {
            t.visit(v);
        }
    }
    t.out
}

/// Each file's edges to the files that define what it names.
fn edges(files: &BTreeMap<ModPath, FileInfo>) -> BTreeMap<ModPath, BTreeSet<ModPath>> {
    let mut edges: BTreeMap<ModPath, BTreeSet<ModPath>> = BTreeMap::new();
    for (module, info) in files {
        let out = edges.entry(module.clone()).or_default();
        for r in &info.refs {
            let to = defining_file(files, r, 0);
            if &to != module {
                out.insert(to);
            }
        }
    }
    edges
}

/// Each cycle as its files, and for each edge inside it one path that makes it.
fn describe(files: &BTreeMap<ModPath, FileInfo>, comps: &[Vec<ModPath>]) -> String {
    let ws = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let name = |m: &ModPath| {
        let p = &files[m].path;
        p.strip_prefix(&ws).unwrap_or(p).display().to_string()
    };
    let mut out = String::new();
    for c in comps {
        let names: Vec<String> = c.iter().map(name).collect();
        out += &format!("cycle: {}\n", names.join(", "));
        for from in c {
            for r in &files[from].refs {
                let to = defining_file(files, r, 0);
                if &to != from && c.contains(&to) {
                    out += &format!(
                        "  {} -> {} (crate::{})\n",
                        name(from),
                        name(&to),
                        r.join("::")
                    );
                }
            }
        }
    }
    out
}

fn assert_acyclic(root: &str) {
    let ws = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let files = module_tree(&ws.join(root));
    assert!(files.len() > 3, "{root}: only {} files found", files.len());
    let comps = cycles(&edges(&files));
    assert!(comps.is_empty(), "{root}:\n{}", describe(&files, &comps));
}

#[test]
fn envs_files_import_no_cycle() {
    assert_acyclic("envs/src/lib.rs");
}

#[test]
fn learner_files_import_no_cycle() {
    assert_acyclic("learner/src/lib.rs");
    assert_acyclic("learner/src/main.rs");
}

/// Every edge from a file under one of `lower` (module paths from the crate root) to
/// a file under one of `upper`, as `from -> to (path)` lines.
fn edges_between(root: &str, lower: &[&str], upper: &[&str]) -> Vec<String> {
    let ws = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let files = module_tree(&ws.join(root));
    let under = |m: &ModPath, tops: &[&str]| m.first().is_some_and(|f| tops.contains(&f.as_str()));
    let mut found = Vec::new();
    for (from, info) in &files {
        if !under(from, lower) {
            continue;
        }
        for r in &info.refs {
            let to = defining_file(&files, r, 0);
            if under(&to, upper) {
                found.push(format!(
                    "{} -> {} (crate::{})",
                    from.join("::"),
                    to.join("::"),
                    r.join("::")
                ));
            }
        }
    }
    found
}

/// The training core (the loop, the objective, the evaluation) hands its records to
/// the logs through `train::RecordSink` and `train::Progress`; it never names the run
/// log, TensorBoard's writer, the progress printer or the sink that joins them.
#[test]
fn the_training_core_does_not_know_the_logs_above_it() {
    let core = ["train", "objective", "eval"];
    let logs = ["runlog", "tboard", "progress", "logs"];
    let found = edges_between("learner/src/lib.rs", &core, &logs);
    assert!(found.is_empty(), "{}", found.join("\n"));
    // The check sees such edges: the logs do import the core.
    assert!(!edges_between("learner/src/lib.rs", &logs, &core).is_empty());
}

#[test]
fn the_check_finds_a_cycle_and_follows_re_exports() {
    let dir = tempfile::tempdir().expect("tempdir");
    let w = |p: &str, s: &str| {
        let path = dir.path().join(p);
        std::fs::create_dir_all(path.parent().expect("folder")).expect("mkdir");
        std::fs::write(path, s).expect("write");
    };
    w(
        "lib.rs",
        "mod a; mod b; mod c; pub use c::C;\n#[cfg(test)] mod tests;",
    );
    w("a.rs", "use crate::C; pub struct A(C);");
    w("b.rs", "pub struct B(crate::a::A);");
    w("c/mod.rs", "mod inner; pub use inner::C;");
    w(
        "c/inner.rs",
        "pub struct C;\n#[cfg(test)] mod t { use crate::b::B; }",
    );
    let files = module_tree(&dir.path().join("lib.rs"));
    let c = |p: &[&str]| p.iter().map(|s| s.to_string()).collect::<ModPath>();
    assert_eq!(
        defining_file(&files, &c(&["C"]), 0),
        c(&["c", "inner"]),
        "re-exports followed"
    );
    assert!(
        cycles(&edges(&files)).is_empty(),
        "test-only imports are not edges"
    );
    // Now inner.rs imports b.rs outside tests: a -> inner -> b -> a.
    w("c/inner.rs", "pub struct C(Box<crate::b::B>);");
    let files = module_tree(&dir.path().join("lib.rs"));
    let found = cycles(&edges(&files));
    assert_eq!(found.len(), 1, "{}", describe(&files, &found));
    assert_eq!(found[0].len(), 3);
}
