//! `#[derive(Params)]`: each config parameter (plant, control, setpoint, supervisor, run, log,
//! realtime and CANopen sections) is declared once, on its struct field, with its unit,
//! admissible range and description (the way a Hopsan component declares
//! `addInputVariable("C_q", "Flow Coefficient", "-", 0.67, &mpCq)`). The derive implements
//! `ehactl_types::spec::ParamTree`, which gives
//!
//! * the registry entries (dotted path, unit, range, description, kind) that the loader's
//!   error messages, `ehactl params`, validation and the Python bindings read, and
//! * a path accessor (`get_path` / `set_path` / `set_path_or_insert`) so that code addressing
//!   a parameter by its dotted path (the fit) never repeats the path beside a hand-written
//!   setter.
//!
//! Field attributes:
//!
//! * `#[param(unit = "kg", range = Positive, desc = "moving mass")]`: a leaf. The kind
//!   follows the type: `f64` and `Option<f64>` are floats, integers (signed or not)
//!   integers, `bool` booleans, `Vec<f64>` float arrays; `choices = EXPR` (a
//!   `&'static [&'static str]`) makes a choice (unit "-", range `Finite` unless given);
//!   a bare `choice` does the same with the serialised variant names of the field's enum
//!   type (`spec::variants`, read from its `Deserialize`, so they cannot drift from what the
//!   loader accepts). `range` is a `spec::Range` variant.
//! * `uncertain(order = N, default, to_range_end)` in a leaf's `#[param(…)]`: the field is a
//!   nominal parameter whose uncertainty a config may state and that `ehactl diagnose`
//!   refits (`spec::Uncertain`: its place `N` in the refit order, refit by default when the
//!   config is silent, its range may reach the registry range's lower end); `role =
//!   loop_param` or `role = flow_gain` in it makes it a parameter of the rig's loop or a
//!   valve flow gain (`spec::Role`), `needs_order = K` refits it only when its section is
//!   configured at model order K; the plant's list of such parameters and the diagnosis'
//!   lists of loop parameters and flow gains are read from these declarations.
//! * `estimated` in a leaf's `#[param(…)]`: the diagnosis estimates the field (or takes it
//!   from the data) rather than trusting the config (`spec::Param::estimated`).
//! * `#[param(nested)]` on a field whose type derives `Params` (or `Option` of one): its
//!   parameters under `<field>.`; `with(field(desc = "…", choices = …, unit = "…",
//!   range = …), …)` overrides an inner field's declaration for this instance (e.g. the two
//!   leakages share one struct but not their descriptions).
//! * Fields without `#[param]` are not parameters (switches, structural enums without a
//!   registry entry, tables).
//!
//! Written with syn/quote, the maintained way to write a derive. The path key of a field is
//! its serde name: the field name, or the string of its `#[serde(rename = "…")]` (read from
//! the same attribute serde reads, so the two can't drift apart); forms the derive cannot
//! follow (`rename(serialize = …)`, `rename_all`, `flatten`) are refused.

use proc_macro::TokenStream;
use proc_macro2::TokenStream as Ts;
use quote::{quote, ToTokens};
use syn::{parse_macro_input, Data, DeriveInput, Expr, Fields, LitStr, Type};

/// Derive `ehactl_types::spec::ParamTree` for a struct with named fields.
#[proc_macro_derive(Params, attributes(param))]
pub fn derive_params(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    match expand(&input) {
        Ok(ts) => ts.into(),
        Err(e) => e.to_compile_error().into(),
    }
}

/// What one `#[param(...)]` or `with(field(...))` says.
#[derive(Default)]
struct Decl {
    unit: Option<LitStr>,
    range: Option<Expr>,
    desc: Option<LitStr>,
    choices: Option<Expr>,
}

/// What `uncertain(order = N, default, to_range_end, role = R, needs_order = K)` says.
struct UncertainDecl {
    order: syn::LitInt,
    default: bool,
    to_range_end: bool,
    /// `loop_param` or `flow_gain` (`spec::Role::Loop` / `FlowGain`); absent: `Nominal`.
    role: Option<syn::Ident>,
    needs_order: Option<syn::LitInt>,
}

impl UncertainDecl {
    fn parse(meta: &syn::meta::ParseNestedMeta) -> syn::Result<UncertainDecl> {
        let (mut order, mut default, mut to_range_end) = (None, false, false);
        let (mut role, mut needs_order) = (None, None);
        meta.parse_nested_meta(|m| {
            if m.path.is_ident("order") {
                order = Some(m.value()?.parse()?);
            } else if m.path.is_ident("role") {
                let r: syn::Ident = m.value()?.parse()?;
                if r != "loop_param" && r != "flow_gain" {
                    return Err(syn::Error::new_spanned(r, "role: expected loop_param or flow_gain"));
                }
                role = Some(r);
            } else if m.path.is_ident("needs_order") {
                needs_order = Some(m.value()?.parse()?);
            } else if m.path.is_ident("default") {
                default = true;
            } else if m.path.is_ident("to_range_end") {
                to_range_end = true;
            } else {
                return Err(m.error(
                    "expected order = N, default, to_range_end, role = loop_param | flow_gain or needs_order = K",
                ));
            }
            Ok(())
        })?;
        let order = order.ok_or_else(|| meta.error("uncertain(…): order = N is required"))?;
        Ok(UncertainDecl {
            order,
            default,
            to_range_end,
            role,
            needs_order,
        })
    }

    fn tokens(&self, sp: &Ts) -> Ts {
        let (o, d, r) = (&self.order, self.default, self.to_range_end);
        let role = match self.role.as_ref().map(|r| r.to_string()).as_deref() {
            Some("loop_param") => quote!(#sp::Role::Loop),
            Some("flow_gain") => quote!(#sp::Role::FlowGain),
            _ => quote!(#sp::Role::Nominal),
        };
        let needs = match &self.needs_order {
            Some(k) => quote!(Some(#k)),
            None => quote!(None),
        };
        quote!(.with_uncertain(#sp::Uncertain {
            order: #o, default: #d, to_range_end: #r, role: #role, needs_order: #needs
        }))
    }
}

impl Decl {
    fn parse_item(&mut self, meta: &syn::meta::ParseNestedMeta) -> syn::Result<bool> {
        if meta.path.is_ident("unit") {
            self.unit = Some(meta.value()?.parse()?);
        } else if meta.path.is_ident("range") {
            self.range = Some(meta.value()?.parse()?);
        } else if meta.path.is_ident("desc") {
            self.desc = Some(meta.value()?.parse()?);
        } else if meta.path.is_ident("choices") {
            self.choices = Some(meta.value()?.parse()?);
        } else {
            return Ok(false);
        }
        Ok(true)
    }
}

enum Shape {
    Float,
    OptFloat,
    Int,
    Bool,
    FloatVec,
    Other,
}

fn shape(ty: &Type) -> Shape {
    let s = ty.to_token_stream().to_string().replace(' ', "");
    match s.as_str() {
        "f64" => Shape::Float,
        "Option<f64>" => Shape::OptFloat,
        "u8" | "u16" | "u32" | "u64" | "usize" | "i8" | "i16" | "i32" | "i64" | "isize" => {
            Shape::Int
        }
        "bool" => Shape::Bool,
        "Vec<f64>" => Shape::FloatVec,
        _ => Shape::Other,
    }
}

/// `Option<T>` → `Some(T)`.
fn option_inner(ty: &Type) -> Option<&Type> {
    let Type::Path(tp) = ty else { return None };
    let seg = tp.path.segments.last()?;
    if seg.ident != "Option" {
        return None;
    }
    let syn::PathArguments::AngleBracketed(args) = &seg.arguments else {
        return None;
    };
    match args.args.first()? {
        syn::GenericArgument::Type(t) => Some(t),
        _ => None,
    }
}

/// Step over the value of a serde item the derive does not read (`= …` or `(…)`).
fn skip_value(m: &syn::meta::ParseNestedMeta) -> syn::Result<()> {
    if m.input.peek(syn::Token![=]) {
        let _: Expr = m.value()?.parse()?;
    } else if m.input.peek(syn::token::Paren) {
        let c;
        syn::parenthesized!(c in m.input);
        let _: Ts = c.parse()?;
    }
    Ok(())
}

fn range_tokens(r: &Expr) -> Ts {
    quote! {{
        #[allow(unused_imports)]
        use ::ehactl_types::spec::Range::*;
        #r
    }}
}

fn expand(input: &DeriveInput) -> syn::Result<Ts> {
    let name = &input.ident;
    let Data::Struct(ds) = &input.data else {
        return Err(syn::Error::new_spanned(name, "Params: only structs"));
    };
    let Fields::Named(fields) = &ds.fields else {
        return Err(syn::Error::new_spanned(name, "Params: only named fields"));
    };
    reject_struct_renames(input)?;
    let sp = quote!(::ehactl_types::spec);
    let mut p = Pieces::default();
    for f in &fields.named {
        let ident = f.ident.as_ref().expect("named field");
        let key = field_key(f)?;
        let Some(attr) = f.attrs.iter().find(|a| a.path().is_ident("param")) else {
            continue;
        };
        let fa = FieldAttr::parse(attr)?;
        if fa.nested {
            p.push_nested(f, ident, &key, &fa, &sp);
        } else {
            p.push_leaf(f, ident, &key, attr, fa, &sp)?;
        }
    }
    Ok(p.impl_tokens(input, &sp))
}

/// A `#[serde(rename_all / rename)]` on the struct: refused (paths are the field names).
fn reject_struct_renames(input: &DeriveInput) -> syn::Result<()> {
    for a in &input.attrs {
        if a.path().is_ident("serde") {
            let mut bad = None;
            let _ = a.parse_nested_meta(|m| {
                if m.path.is_ident("rename_all") || m.path.is_ident("rename") {
                    bad = Some("rename_all / rename on the struct");
                }
                skip_value(&m)
            });
            if let Some(what) = bad {
                return Err(syn::Error::new_spanned(
                    a,
                    format!("Params: serde {what} is not supported (paths are field names)"),
                ));
            }
        }
    }
    Ok(())
}

/// The field's key in parameter paths: its name, or its `#[serde(rename = "…")]`.
fn field_key(f: &syn::Field) -> syn::Result<String> {
    let mut key = f.ident.as_ref().expect("named field").to_string();
    for a in &f.attrs {
        if a.path().is_ident("serde") {
            let mut rename: Option<LitStr> = None;
            let mut unsupported = None;
            let _ = a.parse_nested_meta(|m| {
                if m.path.is_ident("rename") && m.input.peek(syn::Token![=]) {
                    rename = Some(m.value()?.parse()?);
                    return Ok(());
                }
                if m.path.is_ident("rename") || m.path.is_ident("flatten") {
                    unsupported = Some("rename(…) / flatten");
                }
                skip_value(&m)
            });
            if let Some(what) = unsupported {
                return Err(syn::Error::new_spanned(
                    a,
                    format!("Params: serde {what} is not supported; use rename = \"…\""),
                ));
            }
            if let Some(r) = rename {
                key = r.value();
            }
        }
    }
    Ok(key)
}

/// What one field's `#[param(...)]` says.
struct FieldAttr {
    decl: Decl,
    nested: bool,
    choice: bool,
    uncertain: Option<UncertainDecl>,
    /// `estimated`: the diagnosis estimates the field rather than trusting the config.
    estimated: bool,
    with: Vec<(String, Decl)>,
}

impl FieldAttr {
    fn parse(attr: &syn::Attribute) -> syn::Result<FieldAttr> {
        let mut fa = FieldAttr {
            decl: Decl::default(),
            nested: false,
            choice: false,
            uncertain: None,
            estimated: false,
            with: Vec::new(),
        };
        attr.parse_nested_meta(|meta| {
            if meta.path.is_ident("uncertain") {
                fa.uncertain = Some(UncertainDecl::parse(&meta)?);
                return Ok(());
            }
            if meta.path.is_ident("nested") {
                fa.nested = true;
                return Ok(());
            }
            if meta.path.is_ident("estimated") {
                fa.estimated = true;
                return Ok(());
            }
            if meta.path.is_ident("choice") {
                fa.choice = true;
                return Ok(());
            }
            if meta.path.is_ident("with") {
                return meta.parse_nested_meta(|inner| {
                    let field = inner
                        .path
                        .get_ident()
                        .ok_or_else(|| inner.error("expected a field name"))?
                        .to_string();
                    let mut d = Decl::default();
                    inner.parse_nested_meta(|m| {
                        if d.parse_item(&m)? {
                            Ok(())
                        } else {
                            Err(m.error("expected unit, range, desc or choices"))
                        }
                    })?;
                    fa.with.push((field, d));
                    Ok(())
                });
            }
            if fa.decl.parse_item(&meta)? {
                Ok(())
            } else {
                Err(meta.error(
                    "expected unit, range, desc, choices, choice, uncertain(…), estimated, nested or with(...)",
                ))
            }
        })?;
        if fa.nested && (fa.uncertain.is_some() || fa.estimated) {
            return Err(syn::Error::new_spanned(
                attr,
                "param: uncertain(…) and estimated on a leaf, not on a nested section",
            ));
        }
        Ok(fa)
    }
}

/// A `with(field(...))` override as a `spec::Override` literal.
fn override_tokens(field: &str, d: &Decl, sp: &Ts) -> Ts {
    let opt_str = |x: &Option<LitStr>| match x {
        Some(s) => quote!(Some(#s)),
        None => quote!(None),
    };
    let unit = opt_str(&d.unit);
    let desc = opt_str(&d.desc);
    let range = match &d.range {
        Some(r) => {
            let r = range_tokens(r);
            quote!(Some(#r))
        }
        None => quote!(None),
    };
    let choices = match &d.choices {
        Some(c) => quote!(Some(#c)),
        None => quote!(None),
    };
    quote! {
        #sp::Override { field: #field, unit: #unit, range: #range,
                        desc: #desc, choices: #choices }
    }
}

/// The generated pieces of one struct's `ParamTree` impl, gathered field by field.
#[derive(Default)]
struct Pieces {
    declare: Vec<Ts>,
    get_arms: Vec<Ts>,
    set_arms: Vec<Ts>,
    nested_get: Vec<Ts>,
    nested_set: Vec<Ts>,
    vec_get: Vec<Ts>,
    vec_set: Vec<Ts>,
}

impl Pieces {
    /// A nested section (`#[param(nested)]`, optionally `Option<…>`): its declarations
    /// under `key.` and the path forwarding of get / set.
    fn push_nested(
        &mut self,
        f: &syn::Field,
        ident: &syn::Ident,
        key: &str,
        fa: &FieldAttr,
        sp: &Ts,
    ) {
        let (inner, optional) = match option_inner(&f.ty) {
            Some(t) => (t.clone(), true),
            None => (f.ty.clone(), false),
        };
        let overrides = fa
            .with
            .iter()
            .map(|(field, d)| override_tokens(field, d, sp));
        self.declare.push(quote! {
            <#inner as #sp::ParamTree>::declare(
                &#sp::join(prefix, #key), &[#(#overrides),*], out);
        });
        let pfx = format!("{key}.");
        if optional {
            self.nested_get.push(quote! {
                if let Some(rest) = path.strip_prefix(#pfx) {
                    return self.#ident.as_ref().and_then(|s| #sp::ParamTree::param_get(s, rest));
                }
            });
            self.nested_set.push(quote! {
                if let Some(rest) = path.strip_prefix(#pfx) {
                    let tpl = tpl.and_then(|t| t.#ident.as_ref());
                    if self.#ident.is_none() {
                        match tpl {
                            Some(t) => self.#ident = Some(t.clone()),
                            None => {
                                // Unknown paths stay unknown even under an absent section.
                                return if <#inner as #sp::ParamTree>::knows(rest) {
                                    Err(#sp::PathErrorKind::Absent)
                                } else {
                                    Err(#sp::PathErrorKind::Unknown)
                                };
                            }
                        }
                    }
                    return match self.#ident.as_mut() {
                        Some(s) => #sp::ParamTree::param_set(s, rest, v, tpl),
                        None => Err(#sp::PathErrorKind::Absent),
                    };
                }
            });
        } else {
            self.nested_get.push(quote! {
                if let Some(rest) = path.strip_prefix(#pfx) {
                    return #sp::ParamTree::param_get(&self.#ident, rest);
                }
            });
            self.nested_set.push(quote! {
                if let Some(rest) = path.strip_prefix(#pfx) {
                    return #sp::ParamTree::param_set(&mut self.#ident, rest, v, tpl.map(|t| &t.#ident));
                }
            });
        }
    }

    /// A leaf parameter: its declaration (kind, unit, range, description, uncertainty)
    /// and its get / set arms.
    fn push_leaf(
        &mut self,
        f: &syn::Field,
        ident: &syn::Ident,
        key: &str,
        attr: &syn::Attribute,
        fa: FieldAttr,
        sp: &Ts,
    ) -> syn::Result<()> {
        let mut decl = fa.decl;
        if fa.choice {
            if decl.choices.is_some() {
                return Err(syn::Error::new_spanned(
                    attr,
                    "param: choice (from the enum) and choices = … exclude each other",
                ));
            }
            let ty = &f.ty;
            decl.choices = Some(syn::parse_quote!(#sp::variants::<#ty>()));
        }
        let sh = shape(&f.ty);
        let param = leaf_param(&decl, &f.ty, &sh, attr, fa.uncertain.as_ref(), sp)?;
        let param = if fa.estimated {
            quote!(#param.with_estimated())
        } else {
            param
        };
        self.declare.push(quote! {
            out.push((#sp::join(prefix, #key), #sp::Override::apply(over, #key, #param)));
        });
        if decl.choices.is_some() {
            self.get_arms.push(quote!(#key => None,));
            self.set_arms
                .push(quote!(#key => Err(#sp::PathErrorKind::NotFloat),));
            return Ok(());
        }
        self.push_accessors(&sh, ident, key, sp);
        Ok(())
    }

    /// The get / set arms of a leaf of shape `sh` (floats read and written; vectors by index).
    fn push_accessors(&mut self, sh: &Shape, ident: &syn::Ident, key: &str, sp: &Ts) {
        match sh {
            Shape::Float => {
                self.get_arms.push(quote!(#key => Some(self.#ident),));
                self.set_arms
                    .push(quote!(#key => { self.#ident = v; Ok(()) }));
            }
            Shape::OptFloat => {
                self.get_arms.push(quote!(#key => self.#ident,));
                self.set_arms
                    .push(quote!(#key => { self.#ident = Some(v); Ok(()) }));
            }
            Shape::Int | Shape::Bool | Shape::Other => {
                self.get_arms.push(quote!(#key => None,));
                self.set_arms
                    .push(quote!(#key => Err(#sp::PathErrorKind::NotFloat),));
            }
            Shape::FloatVec => {
                self.get_arms.push(quote!(#key => None,));
                self.set_arms
                    .push(quote!(#key => Err(#sp::PathErrorKind::NotFloat),));
                let pfx = format!("{key}[");
                self.vec_get.push(quote! {
                    if let Some(i) = #sp::index_of(path, #pfx) {
                        return self.#ident.get(i).copied();
                    }
                });
                self.vec_set.push(quote! {
                    if let Some(i) = #sp::index_of(path, #pfx) {
                        return match self.#ident.get_mut(i) {
                            Some(x) => { *x = v; Ok(()) }
                            None => Err(#sp::PathErrorKind::Index),
                        };
                    }
                });
            }
        }
    }

    /// The `ParamTree` impl of `input` from the gathered pieces.
    fn impl_tokens(&self, input: &DeriveInput, sp: &Ts) -> Ts {
        let name = &input.ident;
        let Pieces {
            declare,
            get_arms,
            set_arms,
            nested_get,
            nested_set,
            vec_get,
            vec_set,
        } = self;
        let (ig, tg, wc) = input.generics.split_for_impl();
        quote! {
            impl #ig #sp::ParamTree for #name #tg #wc {
                fn declare(
                    prefix: &str,
                    over: &[#sp::Override],
                    out: &mut ::std::vec::Vec<(::std::string::String, #sp::Param)>,
                ) {
                    let _ = over;
                    #(#declare)*
                }
                fn param_get(&self, path: &str) -> Option<f64> {
                    #(#nested_get)*
                    #(#vec_get)*
                    match path {
                        #(#get_arms)*
                        _ => None,
                    }
                }
                fn param_set(&mut self, path: &str, v: f64, tpl: Option<&Self>)
                    -> Result<(), #sp::PathErrorKind> {
                    let _ = tpl;
                    #(#nested_set)*
                    #(#vec_set)*
                    match path {
                        #(#set_arms)*
                        _ => Err(#sp::PathErrorKind::Unknown),
                    }
                }
            }
        }
    }
}

/// A leaf's `spec::Param` expression: kind from the type (or its choices), unit, range,
/// the required description and the optional uncertainty.
fn leaf_param(
    decl: &Decl,
    ty: &Type,
    sh: &Shape,
    attr: &syn::Attribute,
    uncertain: Option<&UncertainDecl>,
    sp: &Ts,
) -> syn::Result<Ts> {
    let desc = decl
        .desc
        .as_ref()
        .ok_or_else(|| syn::Error::new_spanned(attr, "param: desc = \"…\" is required"))?;
    let kind = if let Some(c) = &decl.choices {
        quote!(#sp::Kind::Choice(#c))
    } else {
        match sh {
            Shape::Float | Shape::OptFloat => quote!(#sp::Kind::Float),
            Shape::Int => quote!(#sp::Kind::Integer),
            Shape::Bool => quote!(#sp::Kind::Bool),
            Shape::FloatVec => quote!(#sp::Kind::FloatArray),
            Shape::Other => {
                return Err(syn::Error::new_spanned(
                    ty,
                    "param: type must be f64, Option<f64>, an integer, bool or Vec<f64>, \
                     or the field needs choices = …",
                ))
            }
        }
    };
    let unit = match (&decl.unit, &decl.choices) {
        (Some(u), _) => quote!(#u),
        (None, Some(_)) => quote!("-"),
        (None, None) => {
            return Err(syn::Error::new_spanned(
                attr,
                "param: unit = \"…\" is required",
            ))
        }
    };
    let range = match (&decl.range, &decl.choices) {
        (Some(r), _) => range_tokens(r),
        (None, Some(_)) => quote!(#sp::Range::Finite),
        (None, None) => {
            return Err(syn::Error::new_spanned(
                attr,
                "param: range = … is required",
            ))
        }
    };
    let uncertain = match (uncertain, sh) {
        (None, _) => quote!(),
        (Some(u), Shape::Float | Shape::OptFloat) if decl.choices.is_none() => u.tokens(sp),
        (Some(_), _) => {
            return Err(syn::Error::new_spanned(
                attr,
                "param: uncertain(…) only on a float parameter",
            ))
        }
    };
    Ok(quote!(#sp::Param::new("", #unit, #range, #desc, #kind)#uncertain))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The error `expand` gives for `input`, or `None` if it expands.
    fn error_of(input: DeriveInput) -> Option<String> {
        expand(&input).err().map(|e| e.to_string())
    }

    #[test]
    fn a_complete_leaf_expands_to_its_declaration_and_accessors() {
        let ts = expand(&syn::parse_quote! {
            struct S {
                #[param(unit = "m", range = Positive, desc = "stroke")]
                stroke: f64,
                plain: u32,
            }
        })
        .unwrap()
        .to_string();
        assert!(ts.contains("\"stroke\" => Some (self . stroke)"), "{ts}");
        assert!(ts.contains("\"m\""), "{ts}");
        assert!(
            !ts.contains("plain"),
            "a field without #[param] is not declared: {ts}"
        );
    }

    #[test]
    fn every_missing_or_contradicting_item_is_an_error_naming_it() {
        let cases: [(DeriveInput, &str); 7] = [
            (
                syn::parse_quote! { struct S { #[param(unit = "m", range = Positive)] x: f64 } },
                "desc = \"…\" is required",
            ),
            (
                syn::parse_quote! { struct S { #[param(range = Positive, desc = "d")] x: f64 } },
                "unit = \"…\" is required",
            ),
            (
                syn::parse_quote! { struct S { #[param(unit = "m", desc = "d")] x: f64 } },
                "range = … is required",
            ),
            (
                syn::parse_quote! { struct S { #[param(unit = "m", range = Positive, desc = "d")] x: String } },
                "type must be f64",
            ),
            (
                syn::parse_quote! { struct S { #[param(choice, choices = NAMES, desc = "d")] x: E } },
                "exclude each other",
            ),
            (
                syn::parse_quote! { struct S { #[param(nested, uncertain(order = 1))] x: T } },
                "on a leaf, not on a nested section",
            ),
            (
                syn::parse_quote! { #[serde(rename_all = "snake_case")] struct S { x: f64 } },
                "rename_all / rename on the struct",
            ),
        ];
        for (input, want) in cases {
            let got = error_of(input).unwrap_or_default();
            assert!(
                got.contains(want),
                "expected an error with {want:?}, got {got:?}"
            );
        }
    }

    #[test]
    fn roles_expand_to_their_declaration() {
        let ts = expand(&syn::parse_quote! {
            struct S {
                #[param(unit = "s", range = Finite, desc = "d", uncertain(order = 3, role = loop_param, needs_order = 1))]
                t: f64,
                #[param(unit = "m", range = Finite, desc = "d", estimated)]
                x: f64,
            }
        })
        .unwrap()
        .to_string()
        .replace(' ', "");
        assert!(ts.contains("spec::Role::Loop,"), "{ts}");
        assert!(ts.contains("needs_order:Some(1)"), "{ts}");
        assert!(ts.contains(".with_estimated()"), "{ts}");
        let bad = error_of(syn::parse_quote! {
            struct S { #[param(unit = "s", range = Finite, desc = "d", uncertain(order = 3, role = pump))] t: f64 }
        });
        assert!(
            bad.as_deref()
                .unwrap_or("")
                .contains("expected loop_param or flow_gain"),
            "{bad:?}"
        );
    }

    #[test]
    fn uncertainty_only_on_a_float_leaf() {
        let got = error_of(syn::parse_quote! {
            struct S { #[param(unit = "-", range = Finite, desc = "d", uncertain(order = 1))] n: u32 }
        });
        assert!(
            got.as_deref()
                .unwrap_or("")
                .contains("only on a float parameter"),
            "{got:?}"
        );
    }
}
