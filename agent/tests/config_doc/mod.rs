//! The generator of `docs/config.md`: config structs and enums parsed from their
//! source with `syn` (names, types, doc comments, the serde attributes the configs
//! use), defaults read from a minimal config serialized back to TOML, rendered as one
//! table per section.

mod enums;
mod render;
mod syntax;

use agent::runtime::run_config::TrainConfig;
use agent::sweep::SweepConfig;
use render::{HEADER, dotted, inline, lookup, render};
use syn::{Fields, Item, Type};
use syntax::{Def, Shape, doc_of, serde_of, type_args};

/// The smallest run config: only the required fields.
const RUN_MINIMAL: &str = "[env]\nid = \"\"\n";
/// `RUN_MINIMAL` with one element of each array of tables and each optional section,
/// their required fields only, whose serialized form gives their fields' defaults.
const RUN_ELEMENTS: &str = "[env]\nid = \"\"\n[[learner.objectives]]\nname = \"\"\nepsilon = 0.0\n\
     [learner.conditioning]\nepsilon = {}\n[front]\nreference_point = {}\n";
/// The smallest sweep file.
const SWEEP_MINIMAL: &str =
    "name = \"\"\nbase = \"\"\nreference_point = {}\n[grid]\nkind = \"epsilon\"\n";

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
                panic!("type {name} is not defined in any of {:?}: add its file to SOURCES in agent/tests/config_reference.rs", crate::SOURCES)
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
}

/// The reference text of `sources` (file, text), with the fields that lack a doc
/// comment and the optional ones whose default was not found.
pub(crate) fn generate(sources: &[(String, String)]) -> (String, Vec<String>, Vec<String>) {
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
