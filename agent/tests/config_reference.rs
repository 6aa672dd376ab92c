//! `docs/config.md`, the reference of every run-config and sweep-file field, generated
//! from the config structs themselves: names, types and doc comments parsed from the
//! source with `syn`, defaults from the default config serialized to TOML. The test
//! regenerates it and fails when a field (or enum variant) has no doc comment, or when
//! the committed file differs. After changing a config struct, regenerate it:
//!
//! ```sh
//! UPDATE_CONFIG_REFERENCE=1 cargo test -p agent --test config_reference
//! ```

use std::path::{Path, PathBuf};

use agent::run_config::TrainConfig;
use agent::sweep::SweepConfig;
use syn::{Attribute, Fields, GenericArgument, Item, ItemEnum, ItemStruct, PathArguments, Type};

/// The files that define config structs, relative to `agent/`. A field whose type is
/// defined anywhere else stops the generator with the type's name.
const SOURCES: &[&str] = &[
    "src/run_config/mod.rs",
    "src/config/mod.rs",
    "src/config/mpo.rs",
    "src/config/vmpo.rs",
    "src/config/network.rs",
    "src/config/shared.rs",
    "src/env/connection.rs",
    "src/sweep/config.rs",
    "src/front/mod.rs",
    "src/config/conditioning.rs",
];

/// What the committed reference is compared against.
const REFERENCE: &str = "../docs/config.md";

/// The environment variable that makes the test write the reference instead.
const UPDATE: &str = "UPDATE_CONFIG_REFERENCE";

/// The smallest run config: only the required fields.
const RUN_MINIMAL: &str = "[env]\nid = \"\"\n";
/// `RUN_MINIMAL` with one element of each array of tables and each optional section,
/// their required fields only, whose serialized form gives their fields' defaults.
const RUN_ELEMENTS: &str = "[env]\nid = \"\"\n[[learner.objectives]]\nname = \"\"\nepsilon = 0.0\n\
     [learner.conditioning]\nepsilon = {}\n[front]\nreference_point = {}\n";
/// The smallest sweep file.
const SWEEP_MINIMAL: &str =
    "name = \"\"\nbase = \"\"\nreference_point = {}\n[grid]\nkind = \"epsilon\"\n";

/// A config struct or enum found in `SOURCES`.
enum Def {
    Struct(ItemStruct),
    Enum(ItemEnum),
}

/// The subset of serde attributes the config types use. Anything else (a rename, a
/// flatten, a skip) would make the reference wrong, so it stops the generator.
#[derive(Default)]
struct Serde {
    default: bool,
    tag: Option<String>,
    untagged: bool,
    rename_all: Option<String>,
}

fn serde_of(attrs: &[Attribute], where_: &str) -> Serde {
    let mut s = Serde::default();
    for attr in attrs.iter().filter(|a| a.path().is_ident("serde")) {
        attr.parse_nested_meta(|meta| {
            let key = meta
                .path
                .get_ident()
                .map(ToString::to_string)
                .unwrap_or_default();
            let value = if meta.input.peek(syn::Token![=]) {
                Some(meta.value()?.parse::<syn::LitStr>()?.value())
            } else {
                None
            };
            match key.as_str() {
                "default" => s.default = true,
                "tag" => s.tag = value,
                "untagged" => s.untagged = true,
                "rename_all" => s.rename_all = value,
                "deny_unknown_fields" | "skip_serializing_if" => {}
                other => panic!(
                    "{where_}: #[serde({other})] is not understood by the config reference generator (agent/tests/config_reference.rs)"
                ),
            }
            Ok(())
        })
        .unwrap_or_else(|e| panic!("{where_}: serde attribute: {e}"));
    }
    if let Some(rule) = &s.rename_all {
        assert_eq!(rule, "snake_case", "{where_}: rename_all = {rule:?}");
    }
    s
}

/// The doc comment as one paragraph of text ("" when there is none).
fn doc_of(attrs: &[Attribute]) -> String {
    let lines: Vec<String> = attrs
        .iter()
        .filter(|a| a.path().is_ident("doc"))
        .filter_map(|a| match &a.meta {
            syn::Meta::NameValue(nv) => match &nv.value {
                syn::Expr::Lit(syn::ExprLit {
                    lit: syn::Lit::Str(s),
                    ..
                }) => Some(s.value().trim().to_string()),
                _ => None,
            },
            _ => None,
        })
        .collect();
    lines
        .iter()
        .filter(|l| !l.is_empty())
        .cloned()
        .collect::<Vec<_>>()
        .join(" ")
}

fn snake_case(ident: &str) -> String {
    let mut out = String::new();
    for (i, c) in ident.chars().enumerate() {
        if c.is_uppercase() {
            if i > 0 {
                out.push('_');
            }
            out.extend(c.to_lowercase());
        } else {
            out.push(c);
        }
    }
    out
}

/// What a field holds, in TOML's terms.
enum Shape {
    Scalar(&'static str),
    Array(Box<Shape>),
    Map(Box<Shape>),
    AnyTable,
    Tuple(Vec<Shape>),
    Optional(Box<Shape>),
    Named(String),
}

/// Every type argument of the last path segment.
fn type_args(segment: &syn::PathSegment) -> Vec<&Type> {
    match &segment.arguments {
        PathArguments::AngleBracketed(args) => args
            .args
            .iter()
            .filter_map(|a| match a {
                GenericArgument::Type(t) => Some(t),
                _ => None,
            })
            .collect(),
        _ => Vec::new(),
    }
}

/// The reference generator: the parsed definitions, and what it found missing.
struct Generator {
    defs: Vec<(String, Def)>,
    undocumented: Vec<String>,
    no_default: Vec<String>,
}

/// One table of the reference.
struct Section {
    /// How the table is written in TOML, e.g. `[learner.mpo]`.
    title: String,
    intro: String,
    rows: Vec<Row>,
}

struct Row {
    key: String,
    ty: String,
    default: String,
    meaning: String,
}

/// Defaults of one config kind: the minimal file, and how to read it back serialized.
struct Defaults {
    minimal: &'static str,
    elements: &'static str,
    roundtrip: fn(&str) -> Option<toml::Value>,
}

fn run_roundtrip(text: &str) -> Option<toml::Value> {
    let cfg: TrainConfig = toml::from_str(text).ok()?;
    toml::Value::try_from(cfg).ok()
}

fn sweep_roundtrip(text: &str) -> Option<toml::Value> {
    let cfg: SweepConfig = toml::from_str(text).ok()?;
    toml::Value::try_from(cfg).ok()
}

fn lookup<'a>(value: Option<&'a toml::Value>, key: &str) -> Option<&'a toml::Value> {
    value?.as_table()?.get(key)
}

/// `value` as it would be written in a config, inline.
fn inline(value: &toml::Value) -> String {
    match value {
        toml::Value::String(s) => format!("{s:?}"),
        toml::Value::Array(items) => {
            let items: Vec<String> = items.iter().map(inline).collect();
            format!("[{}]", items.join(", "))
        }
        toml::Value::Table(t) => {
            let items: Vec<String> = t
                .iter()
                .map(|(k, v)| format!("{k} = {}", inline(v)))
                .collect();
            if items.is_empty() {
                "{}".into()
            } else {
                format!("{{ {} }}", items.join(", "))
            }
        }
        // Debug keeps a float's shortest form: 1e-12 rather than 0.000000000001.
        toml::Value::Float(x) => format!("{x:?}"),
        other => other.to_string(),
    }
}

fn cell(text: &str) -> String {
    text.replace('|', "\\|")
}

impl Generator {
    fn new(sources: &[(String, String)]) -> Self {
        let mut defs = Vec::new();
        for (file, text) in sources {
            let parsed = syn::parse_file(text).unwrap_or_else(|e| panic!("{file}: {e}"));
            for item in parsed.items {
                match item {
                    Item::Struct(s) => defs.push((s.ident.to_string(), Def::Struct(s))),
                    Item::Enum(e) => defs.push((e.ident.to_string(), Def::Enum(e))),
                    _ => {}
                }
            }
        }
        Self {
            defs,
            undocumented: Vec::new(),
            no_default: Vec::new(),
        }
    }

    fn def(&self, name: &str) -> &Def {
        self.defs
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, d)| d)
            .unwrap_or_else(|| {
                panic!("type {name} is not defined in any of {SOURCES:?}: add its file to SOURCES in agent/tests/config_reference.rs")
            })
    }

    fn shape(&self, ty: &Type, where_: &str) -> Shape {
        match ty {
            Type::Tuple(t) => Shape::Tuple(t.elems.iter().map(|e| self.shape(e, where_)).collect()),
            Type::Path(p) => {
                let last = p.path.segments.last().expect("a type path has a segment");
                let args = type_args(last);
                match last.ident.to_string().as_str() {
                    "u8" | "u16" | "u32" | "u64" | "usize" | "i8" | "i16" | "i32" | "i64"
                    | "isize" => Shape::Scalar("integer"),
                    "f32" | "f64" => Shape::Scalar("float"),
                    "bool" => Shape::Scalar("boolean"),
                    "String" | "PathBuf" => Shape::Scalar("string"),
                    "Vec" => Shape::Array(Box::new(self.shape(args[0], where_))),
                    "Option" => Shape::Optional(Box::new(self.shape(args[0], where_))),
                    // serde_json::Map<String, Value>: any TOML values.
                    "Map" => Shape::AnyTable,
                    "BTreeMap" | "HashMap" => Shape::Map(Box::new(self.shape(args[1], where_))),
                    name => {
                        self.def(name);
                        Shape::Named(name.to_string())
                    }
                }
            }
            _ => panic!("{where_}: a type the config reference generator does not know"),
        }
    }

    fn type_name(&self, shape: &Shape) -> String {
        match shape {
            Shape::Scalar(s) => (*s).to_string(),
            Shape::Array(inner) => match inner.as_ref() {
                Shape::Named(n) if matches!(self.def(n), Def::Struct(_)) => {
                    "array of tables".into()
                }
                other => format!("array of {}", self.type_name(other)),
            },
            Shape::Map(inner) => format!("table of name = {}", self.type_name(inner)),
            Shape::AnyTable => "table".into(),
            Shape::Tuple(items) => {
                let items: Vec<String> = items.iter().map(|i| self.type_name(i)).collect();
                format!("[{}]", items.join(", "))
            }
            Shape::Optional(inner) => self.type_name(inner),
            Shape::Named(name) => match self.def(name) {
                Def::Struct(_) => "table".into(),
                Def::Enum(e) => {
                    let serde = serde_of(&e.attrs, name);
                    if serde.untagged {
                        let variants: Vec<String> = e
                            .variants
                            .iter()
                            .map(|v| match &v.fields {
                                Fields::Unnamed(f) => {
                                    self.type_name(&self.shape(&f.unnamed[0].ty, name))
                                }
                                Fields::Named(f) => {
                                    let fields: Vec<String> = f
                                        .named
                                        .iter()
                                        .map(|f| {
                                            format!(
                                                "{} = {}",
                                                f.ident.as_ref().unwrap(),
                                                self.type_name(&self.shape(&f.ty, name))
                                            )
                                        })
                                        .collect();
                                    format!("{{ {} }}", fields.join(", "))
                                }
                                Fields::Unit => panic!("{name}: untagged unit variant"),
                            })
                            .collect();
                        variants.join(" or ")
                    } else if let Some(tag) = serde.tag {
                        format!("table with `{tag}`")
                    } else {
                        "string".into()
                    }
                }
            },
        }
    }

    /// The variants of an enum written as strings or tags, with their docs.
    fn variant_list(&mut self, e: &ItemEnum, where_: &str) -> String {
        let mut parts = Vec::new();
        for v in &e.variants {
            let doc = doc_of(&v.attrs);
            let name = snake_case(&v.ident.to_string());
            if doc.is_empty() {
                self.undocumented.push(format!(
                    "{where_} = {name:?} (variant {}::{})",
                    e.ident, v.ident
                ));
            }
            parts.push(format!("`{name:?}`: {}", doc.trim_end_matches('.')));
        }
        format!("One of: {}.", parts.join("; "))
    }

    /// Sections for struct `name` written at `path` (`""` = the top level).
    fn structure(
        &mut self,
        name: &str,
        title: String,
        path: &str,
        defaults: Option<toml::Value>,
        elements: &Defaults,
        out: &mut Vec<Section>,
    ) {
        let Def::Struct(s) = self.def(name) else {
            panic!("{name} is not a struct")
        };
        let s = s.clone();
        let container = serde_of(&s.attrs, name);
        let Fields::Named(fields) = &s.fields else {
            panic!("{name}: a config struct has named fields")
        };
        let index = out.len();
        out.push(Section {
            title,
            intro: doc_of(&s.attrs),
            rows: Vec::new(),
        });
        let mut later = Vec::new();
        for field in &fields.named {
            let key = field.ident.as_ref().expect("named field").to_string();
            let full = if path.is_empty() {
                key.clone()
            } else {
                format!("{path}.{key}")
            };
            let attrs = serde_of(&field.attrs, &full);
            let shape = self.shape(&field.ty, &full);
            let optional =
                container.default || attrs.default || matches!(shape, Shape::Optional(_));
            let value = lookup(defaults.as_ref(), &key).cloned();
            let mut meaning = doc_of(&field.attrs);
            if meaning.is_empty() {
                self.undocumented.push(full.clone());
            }
            let inner = match &shape {
                Shape::Optional(i) | Shape::Array(i) => i.as_ref(),
                other => other,
            };
            let named = match inner {
                Shape::Named(n) => Some(n.clone()),
                _ => None,
            };
            let def_kind = named.as_deref().map(|n| match self.def(n) {
                Def::Struct(_) => "struct",
                Def::Enum(e) if serde_of(&e.attrs, n).tag.is_some() => "tagged",
                Def::Enum(_) => "enum",
            });
            let default = if !optional {
                "required".to_string()
            } else {
                match (&value, &shape) {
                    (Some(v), _) if def_kind != Some("struct") && def_kind != Some("tagged") => {
                        format!("`{}`", inline(v))
                    }
                    (Some(v), Shape::Array(_)) => format!("`{}`", inline(v)),
                    (_, Shape::Optional(_)) if value.is_none() => "unset".into(),
                    (_, _) if def_kind == Some("struct") || def_kind == Some("tagged") => {
                        "see below".into()
                    }
                    _ => {
                        self.no_default.push(full.clone());
                        "?".into()
                    }
                }
            };
            if let Some(Def::Enum(e)) = named.as_deref().map(|n| self.def(n)) {
                let e = e.clone();
                let serde = serde_of(&e.attrs, &full);
                if serde.untagged {
                    // Told apart by their shape (the type column); their docs must exist.
                    for v in &e.variants {
                        if doc_of(&v.attrs).is_empty() {
                            self.undocumented
                                .push(format!("{full} (variant {}::{})", e.ident, v.ident));
                        }
                    }
                } else if serde.tag.is_none() {
                    meaning = format!("{meaning} {}", self.variant_list(&e, &full));
                }
            }
            out[index].rows.push(Row {
                key: key.clone(),
                ty: self.type_name(&shape),
                default,
                meaning,
            });
            match (def_kind, &shape) {
                (Some("struct"), Shape::Array(_)) => later.push((
                    named.unwrap(),
                    format!("`[[{full}]]`"),
                    full.clone(),
                    (elements.roundtrip)(elements.elements).and_then(|v| {
                        dotted(&v, &full).and_then(|a| a.as_array()?.first().cloned())
                    }),
                )),
                (Some("struct"), _) => later.push((
                    named.unwrap(),
                    format!("`[{full}]`"),
                    full.clone(),
                    // An optional section is absent from the defaults: its fields'
                    // defaults come from the elements' config, which sets it.
                    value.clone().or_else(|| {
                        (elements.roundtrip)(elements.elements)
                            .and_then(|v| dotted(&v, &full).cloned())
                    }),
                )),
                (Some("tagged"), _) => later.push((
                    named.unwrap(),
                    format!("`[{full}]`"),
                    full.clone(),
                    value.clone(),
                )),
                _ => {}
            }
        }
        for (name, title, path, value) in later {
            match self.def(&name) {
                Def::Struct(_) => self.structure(&name, title, &path, value, elements, out),
                Def::Enum(_) => self.tagged(&name, title, &path, value, elements, out),
            }
        }
    }

    /// The section of an internally tagged enum: its tag, then every variant's fields.
    fn tagged(
        &mut self,
        name: &str,
        title: String,
        path: &str,
        defaults: Option<toml::Value>,
        elements: &Defaults,
        out: &mut Vec<Section>,
    ) {
        let Def::Enum(e) = self.def(name) else {
            panic!("{name} is not an enum")
        };
        let e = e.clone();
        let tag = serde_of(&e.attrs, name).tag.expect("a tagged enum");
        let mut rows = vec![Row {
            key: tag.clone(),
            ty: "string".into(),
            default: lookup(defaults.as_ref(), &tag)
                .map(|v| format!("`{}`", inline(v)))
                .unwrap_or_else(|| "required".into()),
            meaning: self.variant_list(&e, &format!("{path}.{tag}")),
        }];
        let mut later: Vec<(String, String)> = Vec::new();
        for v in &e.variants {
            let variant = snake_case(&v.ident.to_string());
            let Fields::Named(fields) = &v.fields else {
                continue;
            };
            // The variant's defaults: the minimal config with this variant chosen.
            let chosen = (elements.roundtrip)(&format!(
                "{}\n[{path}]\n{tag} = {variant:?}\n",
                elements.minimal
            ));
            let chosen = chosen.as_ref().and_then(|v| dotted(v, path)).cloned();
            for field in &fields.named {
                let key = field.ident.as_ref().expect("named field").to_string();
                let full = format!("{path}.{key}");
                let attrs = serde_of(&field.attrs, &full);
                let shape = self.shape(&field.ty, &full);
                let doc = doc_of(&field.attrs);
                if doc.is_empty() {
                    self.undocumented
                        .push(format!("{full} ({tag} = {variant:?})"));
                }
                let default = if !attrs.default && !matches!(shape, Shape::Optional(_)) {
                    "required".to_string()
                } else if let Some(v) = lookup(chosen.as_ref(), &key) {
                    format!("`{}`", inline(v))
                } else if matches!(shape, Shape::Optional(_)) {
                    "unset".into()
                } else {
                    self.no_default.push(full.clone());
                    "?".into()
                };
                let inner = match &shape {
                    Shape::Optional(i) | Shape::Array(i) => i.as_ref(),
                    other => other,
                };
                if let Shape::Named(n) = inner
                    && matches!(self.def(n), Def::Struct(_))
                {
                    let title = match &shape {
                        Shape::Array(_) => format!("`[[{full}]]`"),
                        _ => format!("`[{full}]`"),
                    };
                    // One section for a struct several variants hold.
                    if !later.iter().any(|(_, t)| *t == title) {
                        later.push((n.clone(), title));
                    }
                }
                rows.push(Row {
                    key,
                    ty: self.type_name(&shape),
                    default,
                    meaning: format!("With `{tag} = {variant:?}`: {doc}"),
                });
            }
        }
        out.push(Section {
            title,
            intro: doc_of(&e.attrs),
            rows,
        });
        for (name, title) in later {
            let path = title
                .trim_matches(|c| c == '`' || c == '[' || c == ']')
                .to_string();
            self.structure(&name, title, &path, None, elements, out);
        }
    }
}

fn dotted<'a>(value: &'a toml::Value, path: &str) -> Option<&'a toml::Value> {
    path.split('.')
        .try_fold(value, |v, key| v.as_table()?.get(key))
}

fn render(sections: &[Section]) -> String {
    let mut out = String::new();
    for s in sections {
        out.push_str(&format!("### {}\n\n", s.title));
        if !s.intro.is_empty() {
            out.push_str(&format!("{}\n\n", s.intro));
        }
        out.push_str("| Key | Type | Default | Meaning |\n|---|---|---|---|\n");
        for r in &s.rows {
            out.push_str(&format!(
                "| `{}` | {} | {} | {} |\n",
                r.key,
                cell(&r.ty),
                cell(&r.default),
                cell(&r.meaning)
            ));
        }
        out.push('\n');
    }
    out
}

const HEADER: &str = "# Config reference

<!-- Generated by agent/tests/config_reference.rs from the config structs' doc comments; do not edit. -->

Every field of a run config (`agent train --config`, `configs/<algo>/*.toml`) and of a
sweep file (`agent sweep --config`, `configs/sweeps/*.toml`): its TOML type, its default
(\"required\" when it has none) and its meaning. Where a meaning names a table (Table 2,
Table 5, ...), the default is that table's value in Abdolmaleki et al. (2020),
appendix A, and presets in `configs/` override it as their comments say. Every table is
strict: an unknown key is an error that names it. `--set dotted.path=value` overrides
any field from the command line (array elements by index: `learner.objectives.1.epsilon`);
with `train --resume`, only the fields a running run may change (the budget, log and
checkpoint periods, `run.checkpoint_replay`, `run.eval_episodes`, servers, device).

This file is generated from the doc comments of the config structs
(`agent/src/config/`, `agent/src/run_config/`, `agent/src/sweep/config.rs`,
`agent/src/env/connection.rs`) and their `Default`s; a test fails when it is stale or a
field has no doc comment. Regenerate it after changing a config struct:

```sh
UPDATE_CONFIG_REFERENCE=1 cargo test -p agent --test config_reference
```

";

fn generate(sources: &[(String, String)]) -> (String, Vec<String>, Vec<String>) {
    let mut g = Generator::new(sources);
    let run = Defaults {
        minimal: RUN_MINIMAL,
        elements: RUN_ELEMENTS,
        roundtrip: run_roundtrip,
    };
    let sweep = Defaults {
        minimal: SWEEP_MINIMAL,
        elements: SWEEP_MINIMAL,
        roundtrip: sweep_roundtrip,
    };
    let mut run_sections = Vec::new();
    let run_defaults = run_roundtrip(RUN_MINIMAL).expect("the minimal run config loads");
    g.structure(
        "TrainConfig",
        "Top level".into(),
        "",
        Some(run_defaults),
        &run,
        &mut run_sections,
    );
    let mut sweep_sections = Vec::new();
    let sweep_defaults = sweep_roundtrip(SWEEP_MINIMAL).expect("the minimal sweep file loads");
    g.structure(
        "SweepConfig",
        "Top level".into(),
        "",
        Some(sweep_defaults),
        &sweep,
        &mut sweep_sections,
    );
    let text = format!(
        "{HEADER}## Run config\n\n{}## Sweep file\n\n{}",
        render(&run_sections),
        render(&sweep_sections)
    );
    (
        text.trim_end().to_string() + "\n",
        g.undocumented,
        g.no_default,
    )
}

fn read_sources() -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    SOURCES
        .iter()
        .map(|f| {
            let text = std::fs::read_to_string(root.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
            (f.to_string(), text)
        })
        .collect()
}

#[test]
fn docs_config_md_is_generated_from_the_documented_config_structs() {
    let (text, undocumented, no_default) = generate(&read_sources());
    assert!(
        undocumented.is_empty(),
        "config fields without a doc comment (document them in the struct): {undocumented:?}"
    );
    assert!(
        no_default.is_empty(),
        "optional config fields whose default the generator could not find: {no_default:?}"
    );
    let path: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join(REFERENCE);
    if std::env::var_os(UPDATE).is_some() {
        std::fs::write(&path, &text).unwrap();
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == text,
        "docs/config.md is stale (or missing): regenerate it with `{UPDATE}=1 cargo test -p agent --test config_reference` and commit it"
    );
}

#[test]
fn an_undocumented_field_or_variant_is_reported() {
    let mut sources = read_sources();
    let (file, text) = sources
        .iter_mut()
        .find(|(f, _)| f == "src/config/mpo.rs")
        .unwrap();
    let documented = "    /// Table 2 \"batch size\" 512 (snippets per learner step).\n";
    assert!(
        text.contains(documented),
        "{file} changed: update this test"
    );
    *text = text.replace(documented, "");
    let (file, text) = sources
        .iter_mut()
        .find(|(f, _)| f == "src/config/shared.rs")
        .unwrap();
    let documented =
        "    /// eta = exp(p) + 1e-8: one Adam step changes eta by a factor of about\n";
    assert!(
        text.contains(documented),
        "{file} changed: update this test"
    );
    *text = text.replace(documented, "").replace(
        "    /// exp(dual learning rate), whatever its size, so the lag after a reward is\n    /// rescaled grows only with the log of the scale.\n",
        "",
    );
    let (_, undocumented, _) = generate(&sources);
    assert_eq!(
        undocumented,
        vec![
            "learner.mpo.temperature_parameterization = \"log\" (variant TemperatureParameterization::Log)".to_string(),
            "learner.mpo.batch_size".to_string(),
            "learner.vmpo.temperature_parameterization = \"log\" (variant TemperatureParameterization::Log)".to_string(),
        ]
    );
}
