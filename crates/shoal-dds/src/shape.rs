//! The shape of a topic type, read off its serde implementation, and Cyclone's dynamic
//! type made from it.
//!
//! Cyclone checks every sample against its topic's type and computes instance keys from
//! the serialised bytes, so it needs the type's layout: field order, primitive sizes,
//! strings, sequences, arrays, enums, nested structs. `serde-reflection` traces that
//! layout from the same `Deserialize` implementation that decodes the samples, so the
//! two cannot drift apart. Strings and sequences are unbounded here: the IDL's bounds are
//! checked by Shoal's validation, where a violation is reported rather than dropped.
#![allow(unsafe_code)]

use std::ffi::CString;

use cyclors as c;
use serde::de::DeserializeOwned;
use serde_reflection::{ContainerFormat, Format, Registry, Tracer, TracerConfig};

use crate::error::{DdsError, TypeError};

/// A type's layout as serde sees it, with its DDS type name and key fields.
#[derive(Debug)]
pub(crate) struct Shape {
    /// The DDS type name, module-qualified.
    pub(crate) name: String,
    root: String,
    registry: Registry,
    keys: Vec<String>,
}

impl Shape {
    /// Traces `T`, named `type_name` on the wire and keyed by the fields `keys` (none: an
    /// unkeyed topic).
    pub(crate) fn of<T: DeserializeOwned>(
        type_name: &str,
        keys: &[&str],
    ) -> Result<Self, TypeError> {
        let mut tracer = Tracer::new(TracerConfig::default());
        let (format, _) = tracer
            .trace_type_once::<T>(&serde_reflection::Samples::new())
            .map_err(|e| TypeError::Trace {
                type_name: type_name.to_string(),
                detail: e.to_string(),
            })?;
        // Enums need only their kind here (see `named`), not every variant, which a single
        // pass does not always reach (an enum inside a sequence, say).
        let registry = tracer.registry_unchecked();
        let Format::TypeName(root) = format else {
            return Err(TypeError::NotStruct(type_name.to_string()));
        };
        let shape = Self {
            name: type_name.to_string(),
            root,
            registry,
            keys: keys.iter().map(|k| (*k).to_string()).collect(),
        };
        for key in &shape.keys {
            if !shape.root_fields()?.iter().any(|f| &f.name == key) {
                return Err(TypeError::NoKeyField {
                    type_name: type_name.to_string(),
                    key: key.clone(),
                });
            }
        }
        Ok(shape)
    }

    fn root_fields(&self) -> Result<&[serde_reflection::Named<Format>], TypeError> {
        match self.registry.get(&self.root) {
            Some(ContainerFormat::Struct(fields)) => Ok(fields),
            _ => Err(TypeError::NotStruct(self.name.clone())),
        }
    }

    /// Refused: `what` has no DDS equivalent.
    fn unsupported(&self, what: String) -> TypeError {
        TypeError::Unsupported {
            type_name: self.name.clone(),
            what,
        }
    }

    /// A count or index as the 32 bits DDS has for it.
    fn u32(&self, n: usize, what: &str) -> Result<u32, TypeError> {
        u32::try_from(n).map_err(|_| self.unsupported(format!("{n} {what}")))
    }

    /// The module prefix of the DDS type name ("shoal::"), for nested types' names.
    fn module(&self) -> &str {
        self.name.rfind("::").map_or("", |i| &self.name[..i + 2])
    }
}

/// A dynamic type under construction, unreferenced on drop.
pub(crate) struct DynamicType(c::dds_dynamic_type_t);

impl DynamicType {
    /// The raw type, for registration.
    pub(crate) fn raw(&mut self) -> *mut c::dds_dynamic_type_t {
        &raw mut self.0
    }

    /// Builds `shape`'s dynamic type in `entity`'s domain.
    pub(crate) fn build(entity: c::dds_entity_t, shape: &Shape) -> Result<Self, TypeError> {
        let mut b = Builder {
            entity,
            shape,
            names: Vec::new(),
            anonymous: 0,
        };
        let fields = shape.root_fields()?;
        let mut ty = b.structure(&shape.name, fields)?;
        for (i, f) in fields.iter().enumerate() {
            if shape.keys.contains(&f.name) {
                let id = shape.u32(i, "fields")?;
                // SAFETY: ty is a struct under construction with member `id`.
                let ret = unsafe { c::dds_dynamic_member_set_key(&raw mut ty.0, id, true) };
                check(ret, shape, "key")?;
            }
        }
        Ok(ty)
    }
}

impl Drop for DynamicType {
    fn drop(&mut self) {
        // SAFETY: releases the reference this value holds.
        unsafe {
            c::dds_dynamic_type_unref(&raw mut self.0);
        }
    }
}

/// A dynamic-type call's return code: an error naming the step when negative.
fn check(ret: i32, shape: &Shape, step: &str) -> Result<(), TypeError> {
    if ret < 0 {
        Err(refused(shape, step, crate::cyclone::error(ret)))
    } else {
        Ok(())
    }
}

/// Cyclone refused `step` of building `shape`'s type.
fn refused(shape: &Shape, step: &str, source: DdsError) -> TypeError {
    TypeError::Dds {
        type_name: shape.name.clone(),
        step: step.to_string(),
        source,
    }
}

struct Builder<'a> {
    entity: c::dds_entity_t,
    shape: &'a Shape,
    /// C strings that must live until the type is complete.
    names: Vec<CString>,
    anonymous: u32,
}

/// How a member's type is given to Cyclone.
enum Spec {
    Primitive(c::dds_dynamic_type_kind_t),
    /// A type made here, whose reference moves into the parent.
    Made(DynamicType),
}

impl Builder<'_> {
    fn cname(&mut self, s: &str) -> Result<*const std::os::raw::c_char, TypeError> {
        let c = CString::new(s)
            .map_err(|_| refused(self.shape, "name", DdsError::Nul(s.to_string())))?;
        let p = c.as_ptr();
        self.names.push(c);
        Ok(p)
    }

    fn anonymous_name(&mut self, what: &str) -> String {
        self.anonymous += 1;
        format!("{}{what}_{}", self.shape.module(), self.anonymous)
    }

    fn create(&mut self, d: c::dds_dynamic_type_descriptor_t) -> Result<DynamicType, TypeError> {
        // SAFETY: the descriptor's strings and bounds outlive the call (self.names, or
        // the caller's stack); the entity is a live participant.
        let t = unsafe { c::dds_dynamic_type_create(self.entity, d) };
        check(t.ret, self.shape, "create a type")?;
        Ok(DynamicType(t))
    }

    fn descriptor(kind: c::dds_dynamic_type_kind_t) -> c::dds_dynamic_type_descriptor_t {
        // SAFETY: a plain C struct for which all-zero is "unset".
        let mut d: c::dds_dynamic_type_descriptor_t = unsafe { std::mem::zeroed() };
        d.kind = kind;
        d
    }

    fn structure(
        &mut self,
        name: &str,
        fields: &[serde_reflection::Named<Format>],
    ) -> Result<DynamicType, TypeError> {
        let mut d = Self::descriptor(c::dds_dynamic_type_kind_DDS_DYNAMIC_STRUCTURE);
        d.name = self.cname(name)?;
        let mut ty = self.create(d)?;
        // SAFETY: ty is a struct under construction.
        let ret = unsafe {
            c::dds_dynamic_type_set_extensibility(
                &raw mut ty.0,
                c::dds_dynamic_type_extensibility_DDS_DYNAMIC_TYPE_EXT_FINAL,
            )
        };
        check(ret, self.shape, "extensibility")?;
        for (i, f) in fields.iter().enumerate() {
            let spec = self.spec(&f.value)?;
            // SAFETY: a plain C struct for which all-zero is "unset".
            let mut m: c::dds_dynamic_member_descriptor_t = unsafe { std::mem::zeroed() };
            m.name = self.cname(&f.name)?;
            m.id = self.shape.u32(i, "fields")?;
            m.index = u32::MAX;
            m.type_ = Self::type_spec(spec);
            // SAFETY: ty is under construction; the member's type reference moves into it.
            let ret = unsafe { c::dds_dynamic_type_add_member(&raw mut ty.0, m) };
            check(ret, self.shape, &format!("member {}", f.name))?;
        }
        Ok(ty)
    }

    fn type_spec(spec: Spec) -> c::dds_dynamic_type_spec_t {
        // SAFETY: a plain C struct for which all-zero is "unset".
        let mut s: c::dds_dynamic_type_spec_t = unsafe { std::mem::zeroed() };
        match spec {
            Spec::Primitive(p) => {
                s.kind = c::dds_dynamic_type_spec_kind_DDS_DYNAMIC_TYPE_KIND_PRIMITIVE;
                s.type_.primitive = p;
            }
            Spec::Made(t) => {
                s.kind = c::dds_dynamic_type_spec_kind_DDS_DYNAMIC_TYPE_KIND_DEFINITION;
                // The reference moves to Cyclone with the spec.
                s.type_.type_ = std::mem::ManuallyDrop::new(t).0;
            }
        }
        s
    }

    fn collection(
        &mut self,
        kind: c::dds_dynamic_type_kind_t,
        element: &Format,
        bound: Option<u32>,
    ) -> Result<Spec, TypeError> {
        let element = self.spec(element)?;
        let what = if bound.is_some() { "array" } else { "sequence" };
        let name = self.anonymous_name(what);
        let mut d = Self::descriptor(kind);
        d.name = self.cname(&name)?;
        let bounds = [bound.unwrap_or(0)];
        if bound.is_some() {
            d.num_bounds = 1;
            d.bounds = bounds.as_ptr();
        }
        d.element_type = Self::type_spec(element);
        Ok(Spec::Made(self.create(d)?))
    }

    fn spec(&mut self, format: &Format) -> Result<Spec, TypeError> {
        use c::{
            dds_dynamic_type_kind_DDS_DYNAMIC_ARRAY as ARRAY,
            dds_dynamic_type_kind_DDS_DYNAMIC_SEQUENCE as SEQUENCE,
        };
        let p = Spec::Primitive;
        Ok(match format {
            Format::Bool => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_BOOLEAN),
            Format::I8 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_INT8),
            Format::I16 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_INT16),
            Format::I32 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_INT32),
            Format::I64 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_INT64),
            Format::U8 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_UINT8),
            Format::U16 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_UINT16),
            Format::U32 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_UINT32),
            Format::U64 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_UINT64),
            Format::F32 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_FLOAT32),
            Format::F64 => p(c::dds_dynamic_type_kind_DDS_DYNAMIC_FLOAT64),
            Format::Str => {
                let d = Self::descriptor(c::dds_dynamic_type_kind_DDS_DYNAMIC_STRING8);
                Spec::Made(self.create(d)?)
            }
            Format::Bytes => self.collection(SEQUENCE, &Format::U8, None)?,
            Format::Seq(element) => self.collection(SEQUENCE, element, None)?,
            Format::TupleArray { content, size } => {
                let size = self.shape.u32(*size, "array elements")?;
                self.collection(ARRAY, content, Some(size))?
            }
            Format::Tuple(items) if !items.is_empty() && items.iter().all(|i| *i == items[0]) => {
                let size = self.shape.u32(items.len(), "tuple elements")?;
                self.collection(ARRAY, &items[0], Some(size))?
            }
            Format::TypeName(name) => self.named(name)?,
            other => return Err(self.shape.unsupported(format!("{other:?}"))),
        })
    }

    fn named(&mut self, name: &str) -> Result<Spec, TypeError> {
        let container = self.shape.registry.get(name).cloned().ok_or_else(|| {
            self.shape
                .unsupported(format!("{name}, whose layout was not traced"))
        })?;
        let suffix = if self.shape.name.ends_with('_') {
            "_"
        } else {
            ""
        };
        let dds_name = format!("{}{name}{suffix}", self.shape.module());
        Ok(match container {
            ContainerFormat::Struct(fields) => Spec::Made(self.structure(&dds_name, &fields)?),
            ContainerFormat::NewTypeStruct(inner) => self.spec(&inner)?,
            ContainerFormat::TupleStruct(items) => self.spec(&Format::Tuple(items))?,
            ContainerFormat::Enum(variants) => {
                // A C-like enum is its variant's 32-bit index on the wire (XCDR1), the same
                // bytes as an int32. No type information is exchanged (see `cyclone::topic`),
                // so Cyclone need not know the literals; decoding in Shoal rejects an unknown
                // value and reports the sample as malformed.
                if variants
                    .values()
                    .any(|v| !matches!(v.value, serde_reflection::VariantFormat::Unit))
                {
                    return Err(self.shape.unsupported(format!("enum {name} carrying data")));
                }
                Spec::Primitive(c::dds_dynamic_type_kind_DDS_DYNAMIC_INT32)
            }
            ContainerFormat::UnitStruct => {
                return Err(self.shape.unsupported(format!("unit struct {name}")));
            }
        })
    }
}
