//! Enums in the reference: a plain enum as the list of its values, an internally
//! tagged one as a section of its tag followed by each variant's own fields.

use syn::{Fields, ItemEnum};

use super::render::{dotted, inline, lookup};
use super::syntax::{Def, Shape, doc_of, serde_of, snake_case};
use super::{Defaults, Generator, Row, Section};

impl Generator {
    /// The variants of an enum written as strings or tags, with their docs.
    pub(super) fn variant_list(&mut self, e: &ItemEnum, where_: &str) -> String {
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

    /// The section of an internally tagged enum: its tag, then every variant's fields.
    pub(super) fn tagged(
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
