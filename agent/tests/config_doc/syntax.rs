//! What the generator reads from a config source: its definitions, the serde
//! attributes the configs use, doc comments, and what a field's type holds.

use syn::{Attribute, GenericArgument, ItemEnum, ItemStruct, PathArguments, Type};

/// A config struct or enum found in `SOURCES`.
pub(crate) enum Def {
    Struct(ItemStruct),
    Enum(ItemEnum),
}

/// The subset of serde attributes the config types use. Anything else (a rename, a
/// flatten, a skip) would make the reference wrong, so it stops the generator.
#[derive(Default)]
pub(crate) struct Serde {
    pub(crate) default: bool,
    pub(crate) tag: Option<String>,
    pub(crate) untagged: bool,
    pub(crate) rename_all: Option<String>,
}

pub(crate) fn serde_of(attrs: &[Attribute], where_: &str) -> Serde {
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
pub(crate) fn doc_of(attrs: &[Attribute]) -> String {
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

pub(crate) fn snake_case(ident: &str) -> String {
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
pub(crate) enum Shape {
    Scalar(&'static str),
    Array(Box<Shape>),
    Map(Box<Shape>),
    AnyTable,
    Tuple(Vec<Shape>),
    Optional(Box<Shape>),
    Named(String),
}

/// Every type argument of the last path segment.
pub(crate) fn type_args(segment: &syn::PathSegment) -> Vec<&Type> {
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
