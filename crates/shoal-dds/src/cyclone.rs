//! The one place Shoal calls Cyclone DDS's C API; everything above it is safe Rust.
//!
//! - [`Entity`] owns a Cyclone entity handle and deletes it (and its children) on drop.
//! - [`Qos`] owns a QoS object.
//! - [`domain`] creates each DDS domain once per process, with the XML configuration
//!   made from [`DdsConfig`] (interfaces, multicast for discovery only, socket buffers).
//! - [`write_cdr`] and [`take_cdr`] move samples as serialised CDR, so Shoal's serde types
//!   never need a C layout: Cyclone checks ("normalises") every incoming sample against the
//!   topic's type before it is delivered, and computes keys from the bytes.
//! - Cyclone's log goes to `tracing`; samples it could not deserialise are counted per
//!   topic ([`malformed_since`]), since the library drops them before any reader sees them.
#![allow(unsafe_code)]

use std::collections::HashMap;
use std::ffi::{CStr, CString, c_void};
use std::ptr::{null, null_mut};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use cyclors as c;

use crate::config::DdsConfig;
use crate::error::{CreateError, DdsError, TypeError};

/// A Cyclone return code in words.
fn retcode(ret: i32) -> String {
    // SAFETY: dds_strretcode returns a pointer to a static string for any value.
    let s = unsafe { CStr::from_ptr(c::dds_strretcode(ret)) };
    s.to_string_lossy().into_owned()
}

/// The error for a Cyclone return code.
pub(crate) fn error(code: i32) -> DdsError {
    DdsError::Code {
        code,
        message: retcode(code),
    }
}

/// `s` as a C string.
fn c_string(s: &str) -> Result<CString, DdsError> {
    CString::new(s).map_err(|_| DdsError::Nul(s.to_string()))
}

/// A Cyclone entity (participant, topic, reader, writer), deleted with its children on drop.
#[derive(Debug)]
pub(crate) struct Entity(c::dds_entity_t);

impl Entity {
    /// Wraps a handle a `dds_create_*` call returned; negative values are error codes.
    pub(crate) fn new(handle: c::dds_entity_t) -> Result<Self, DdsError> {
        if handle < 0 {
            Err(error(handle))
        } else {
            Ok(Self(handle))
        }
    }

    /// A handle to pass where the entity is only used (a topic for its endpoints).
    pub(crate) fn topic_ref(&self) -> TopicRef {
        TopicRef(self.0)
    }
}

/// A topic used by reference; the topic itself is owned elsewhere and outlives the use.
#[derive(Debug, Clone, Copy)]
pub(crate) struct TopicRef(c::dds_entity_t);

impl Drop for Entity {
    fn drop(&mut self) {
        // SAFETY: deleting a handle is safe whatever its state: one already deleted (with
        // its parent) returns an error, which is of no interest here. Cyclone waits for
        // listener calls on the entity in progress before it returns.
        unsafe {
            c::dds_delete(self.0);
        }
    }
}

/// A 16-byte DDS GUID (12-byte participant prefix, 4-byte entity id).
pub(crate) type Guid = [u8; 16];

/// The GUID of an entity.
pub(crate) fn guid(entity: &Entity) -> Guid {
    guid_of(entity.0)
}

fn guid_of(handle: c::dds_entity_t) -> Guid {
    let mut g = c::dds_guid_t { v: [0; 16] };
    // SAFETY: `g` is a valid out-parameter; a failure leaves it zero.
    unsafe {
        c::dds_get_guid(handle, &raw mut g);
    }
    g.v
}

/// Reliability of an endpoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Reliability {
    /// Best effort.
    BestEffort,
    /// Reliable; a write may block this long when the history is full of unacknowledged data.
    Reliable(std::time::Duration),
}

fn ns(d: std::time::Duration) -> i64 {
    i64::try_from(d.as_nanos()).unwrap_or(i64::MAX)
}

/// A Cyclone QoS object, freed on drop.
#[derive(Debug)]
pub(crate) struct Qos(*mut c::dds_qos_t);

impl Qos {
    /// An empty QoS (every policy at Cyclone's default).
    pub(crate) fn new() -> Self {
        // SAFETY: allocation; never null (Cyclone aborts on out of memory).
        Self(unsafe { c::dds_create_qos() })
    }

    pub(crate) fn reliability(&mut self, r: Reliability) {
        // SAFETY: self.0 is a live QoS object.
        unsafe {
            match r {
                Reliability::BestEffort => c::dds_qset_reliability(
                    self.0,
                    c::dds_reliability_kind_DDS_RELIABILITY_BEST_EFFORT,
                    0,
                ),
                Reliability::Reliable(max_blocking) => c::dds_qset_reliability(
                    self.0,
                    c::dds_reliability_kind_DDS_RELIABILITY_RELIABLE,
                    ns(max_blocking),
                ),
            }
        }
    }

    pub(crate) fn transient_local(&mut self, yes: bool) {
        let kind = if yes {
            c::dds_durability_kind_DDS_DURABILITY_TRANSIENT_LOCAL
        } else {
            c::dds_durability_kind_DDS_DURABILITY_VOLATILE
        };
        // SAFETY: self.0 is a live QoS object.
        unsafe { c::dds_qset_durability(self.0, kind) }
    }

    pub(crate) fn keep_last(&mut self, depth: i32) {
        // SAFETY: self.0 is a live QoS object.
        unsafe { c::dds_qset_history(self.0, c::dds_history_kind_DDS_HISTORY_KEEP_LAST, depth) }
    }

    pub(crate) fn deadline(&mut self, d: std::time::Duration) {
        // SAFETY: self.0 is a live QoS object.
        unsafe { c::dds_qset_deadline(self.0, ns(d)) }
    }

    pub(crate) fn automatic_liveliness(&mut self, lease: std::time::Duration) {
        // SAFETY: self.0 is a live QoS object.
        unsafe {
            c::dds_qset_liveliness(
                self.0,
                c::dds_liveliness_kind_DDS_LIVELINESS_AUTOMATIC,
                ns(lease),
            );
        }
    }

    pub(crate) fn resource_limits(&mut self, samples: i32, instances: i32, per_instance: i32) {
        // SAFETY: self.0 is a live QoS object.
        unsafe { c::dds_qset_resource_limits(self.0, samples, instances, per_instance) }
    }

    /// The PARTITION policy: the names a writer publishes in, or the names (and `*`
    /// patterns) a reader listens to.
    pub(crate) fn partitions(&mut self, names: &[&str]) -> Result<(), DdsError> {
        let owned: Vec<CString> = names
            .iter()
            .map(|n| c_string(n))
            .collect::<Result<_, _>>()?;
        let mut ptrs: Vec<*const std::os::raw::c_char> = owned.iter().map(|c| c.as_ptr()).collect();
        let n = u32::try_from(ptrs.len()).unwrap_or(u32::MAX);
        // SAFETY: self.0 is live; `ptrs` points at `owned`'s C strings, both alive for the
        // call; Cyclone copies the strings.
        unsafe { c::dds_qset_partition(self.0, n, ptrs.as_mut_ptr()) };
        Ok(())
    }

    /// A PROPERTY policy entry (DDS Security reads its configuration from these).
    pub(crate) fn property(&mut self, name: &str, value: &str) -> Result<(), DdsError> {
        let (n, v) = (c_string(name)?, c_string(value)?);
        // SAFETY: self.0 is live; both C strings live for the call; Cyclone copies them.
        unsafe { c::dds_qset_prop(self.0, n.as_ptr(), v.as_ptr()) };
        Ok(())
    }

    /// Plain CDR version 1 only: Shoal's codec reads no XCDR2, so writers offering only
    /// XCDR2 must not match rather than deliver samples nobody can decode.
    pub(crate) fn xcdr1_only(&mut self) {
        let ids = [c::DDS_DATA_REPRESENTATION_XCDR1 as i16];
        // SAFETY: self.0 is live; Cyclone copies the one-element array.
        unsafe { c::dds_qset_data_representation(self.0, 1, ids.as_ptr()) }
    }

    pub(crate) fn entity_name(&mut self, name: &str) {
        if let Ok(name) = CString::new(name) {
            // SAFETY: self.0 is a live QoS object; Cyclone copies the string.
            unsafe { c::dds_qset_entity_name(self.0, name.as_ptr()) }
        }
    }

    fn ptr(&self) -> *const c::dds_qos_t {
        self.0
    }
}

impl Drop for Qos {
    fn drop(&mut self) {
        // SAFETY: self.0 came from dds_create_qos and is freed once.
        unsafe { c::dds_delete_qos(self.0) }
    }
}

// A QoS object is plain data owned by this value.
// SAFETY: nothing else holds the pointer.
unsafe impl Send for Qos {}

/// The DDS domains this process has created: one configuration per domain id.
static DOMAINS: Mutex<Vec<(u16, String, Entity)>> = Mutex::new(Vec::new());

/// The Cyclone XML configuration of `config`'s domain.
pub(crate) fn domain_xml(config: &DdsConfig) -> String {
    let interfaces: String = config
        .interfaces
        .iter()
        .map(|a| {
            // Cyclone treats loopback as unable to multicast unless told otherwise, and
            // discovery on loopback (every test, the default) needs it.
            let multicast = if a.is_loopback() { "true" } else { "default" };
            format!(r#"<NetworkInterface address="{a}" multicast="{multicast}"/>"#)
        })
        .collect();
    format!(
        "<CycloneDDS><Domain id=\"any\"><General><Interfaces>{interfaces}</Interfaces>\
         <AllowMulticast>spdp</AllowMulticast></General>\
         <Internal><SocketReceiveBufferSize min=\"{}B\"/>\
         <MaxSampleSize>{}B</MaxSampleSize></Internal></Domain></CycloneDDS>",
        config.socket_receive_buffer, config.max_sample_bytes
    )
}

/// Creates `config`'s domain unless this process already has it; a second configuration
/// for the same domain id is an error (Cyclone has one per domain and process).
pub(crate) fn domain(config: &DdsConfig) -> Result<(), DdsError> {
    install_log_sink();
    let xml = domain_xml(config);
    let mut domains = DOMAINS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some((_, existing, _)) = domains.iter().find(|(id, _, _)| *id == config.domain_id) {
        return if *existing == xml {
            Ok(())
        } else {
            Err(DdsError::DomainConflict(config.domain_id))
        };
    }
    let cxml = c_string(&xml)?;
    // SAFETY: a valid C string; Cyclone parses it and copies what it needs.
    let handle = unsafe { c::dds_create_domain(u32::from(config.domain_id), cxml.as_ptr()) };
    let entity = Entity::new(handle)?;
    domains.push((config.domain_id, xml, entity));
    Ok(())
}

/// Joins `domain_id` (created with [`domain`]) as a participant named `name`, with
/// `properties` (DDS Security's configuration, when it is on) in its QoS.
pub(crate) fn participant(
    domain_id: u16,
    name: &str,
    properties: &[(String, String)],
) -> Result<Entity, DdsError> {
    let mut qos = Qos::new();
    qos.entity_name(name);
    for (k, v) in properties {
        qos.property(k, v)?;
    }
    // SAFETY: the domain exists; QoS is live for the call; no listener.
    Entity::new(unsafe { c::dds_create_participant(u32::from(domain_id), qos.ptr(), null()) })
}

/// Writers' and readers' incompatible-QoS reports, as the participant's listener saw them.
#[derive(Debug, Default)]
pub(crate) struct QosReports {
    /// (reader or writer GUID hex, "requested"/"offered", the policy's name).
    pub(crate) events: Mutex<Vec<(String, bool, &'static str)>>,
}

fn policy_name(id: u32) -> &'static str {
    match id {
        2 => "durability",
        4 => "deadline",
        5 => "latency budget",
        6 => "ownership",
        8 => "liveliness",
        11 => "reliability",
        12 => "destination order",
        13 => "history",
        14 => "resource limits",
        23 => "data representation",
        _ => "a policy",
    }
}

unsafe extern "C" fn on_requested_incompatible(
    reader: c::dds_entity_t,
    status: c::dds_requested_incompatible_qos_status_t,
    arg: *mut c_void,
) {
    // SAFETY: arg is the Arc<QosReports> the participant's listener was created with; the
    // participant is deleted (which ends listener calls) before that Arc is released.
    let reports = unsafe { &*(arg as *const QosReports) };
    let id = hex::encode(guid_of(reader));
    if let Ok(mut e) = reports.events.lock() {
        e.push((id, true, policy_name(status.last_policy_id)));
    }
}

unsafe extern "C" fn on_offered_incompatible(
    writer: c::dds_entity_t,
    status: c::dds_offered_incompatible_qos_status_t,
    arg: *mut c_void,
) {
    // SAFETY: as in on_requested_incompatible.
    let reports = unsafe { &*(arg as *const QosReports) };
    let id = hex::encode(guid_of(writer));
    if let Ok(mut e) = reports.events.lock() {
        e.push((id, false, policy_name(status.last_policy_id)));
    }
}

/// A listener object, freed on drop (Cyclone copies it into the entities it is given to).
struct Listener(*mut c::dds_listener_t);

impl Listener {
    fn new(arg: *const c_void) -> Self {
        // SAFETY: allocation; every callback starts unset (handled by the parent entity).
        Self(unsafe { c::dds_create_listener(arg.cast_mut()) })
    }
}

impl Drop for Listener {
    fn drop(&mut self) {
        // SAFETY: self.0 came from dds_create_listener and is freed once.
        unsafe { c::dds_delete_listener(self.0) }
    }
}

/// Puts the incompatible-QoS listener on a participant, for all its readers and writers.
pub(crate) fn listen_for_qos(participant: &Entity, reports: &Arc<QosReports>) {
    let l = Listener::new(Arc::as_ptr(reports).cast());
    // SAFETY: l.0 is live; the callbacks match Cyclone's signatures.
    unsafe {
        c::dds_lset_requested_incompatible_qos(l.0, Some(on_requested_incompatible));
        c::dds_lset_offered_incompatible_qos(l.0, Some(on_offered_incompatible));
        c::dds_set_listener(participant.0, l.0);
    }
}

/// A topic's registered type: the sertype serialised samples are made with.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SerType(*const c::ddsi_sertype);

// SAFETY: a sertype is immutable once its topic exists and Cyclone shares it across
// threads itself; it lives as long as the topic, which outlives every use here.
unsafe impl Send for SerType {}
// SAFETY: as above.
unsafe impl Sync for SerType {}

/// The sertype of a topic, reader or writer.
pub(crate) fn sertype(entity: &Entity) -> Result<SerType, DdsError> {
    let mut st: *const c::ddsi_sertype = null();
    // SAFETY: `st` is a valid out-parameter.
    let ret = unsafe { c::dds_get_entity_sertype(entity.0, &raw mut st) };
    if ret < 0 || st.is_null() {
        return Err(error(ret.min(c::DDS_RETCODE_ERROR)));
    }
    Ok(SerType(st))
}

/// Creates a topic of a type built by `build` (a dynamic type registered with Cyclone).
pub(crate) fn topic(
    participant: &Entity,
    name: &str,
    ty: &crate::shape::Shape,
    qos: &Qos,
) -> Result<Entity, CreateError> {
    let refused = |source| CreateError::Dds {
        what: format!("topic {name}"),
        source,
    };
    let type_refused = |step: &str, ret: i32| CreateError::Type {
        topic: name.to_string(),
        source: TypeError::Dds {
            type_name: ty.name.clone(),
            step: step.to_string(),
            source: error(ret.min(c::DDS_RETCODE_ERROR)),
        },
    };
    let cname = c_string(name).map_err(refused)?;
    let mut built = crate::shape::DynamicType::build(participant.0, ty).map_err(|source| {
        CreateError::Type {
            topic: name.to_string(),
            source,
        }
    })?;
    let mut type_info: *mut c::dds_typeinfo_t = null_mut();
    // SAFETY: `built` is a complete dynamic type; registering consumes nothing.
    let ret = unsafe { c::dds_dynamic_type_register(built.raw(), &raw mut type_info) };
    if ret < 0 {
        return Err(type_refused("register", ret));
    }
    let mut descriptor: *mut c::dds_topic_descriptor_t = null_mut();
    // SAFETY: type_info came from the registration above.
    let ret = unsafe {
        c::dds_create_topic_descriptor(
            c::dds_find_scope_DDS_FIND_SCOPE_LOCAL_DOMAIN,
            participant.0,
            type_info,
            0,
            &raw mut descriptor,
        )
    };
    // SAFETY: type_info is freed once, after its last use.
    unsafe { c::dds_free_typeinfo(type_info) };
    if ret < 0 || descriptor.is_null() {
        return Err(type_refused("topic descriptor", ret));
    }
    // Match remote endpoints on the type's name, as RustDDS, Fast DDS and RTI without
    // XTypes do: announce no TypeInformation (docs/deviations.md, "Type matching").
    // SAFETY: descriptor is live; the fields are put back before it is deleted.
    let handle = unsafe {
        let d = &mut *descriptor;
        let saved = (d.type_information, d.type_mapping, d.m_flagset);
        d.type_information = c::dds_type_meta_ser {
            data: null_mut(),
            sz: 0,
        };
        d.type_mapping = c::dds_type_meta_ser {
            data: null_mut(),
            sz: 0,
        };
        d.m_flagset &= !c::DDS_TOPIC_XTYPES_METADATA;
        let h = c::dds_create_topic(participant.0, descriptor, cname.as_ptr(), qos.ptr(), null());
        let d = &mut *descriptor;
        (d.type_information, d.type_mapping, d.m_flagset) = saved;
        c::dds_delete_topic_descriptor(descriptor);
        h
    };
    Entity::new(handle).map_err(refused)
}

/// Creates a writer.
pub(crate) fn writer(participant: &Entity, topic: TopicRef, qos: &Qos) -> Result<Entity, DdsError> {
    // SAFETY: live entities and QoS; no listener.
    Entity::new(unsafe { c::dds_create_writer(participant.0, topic.0, qos.ptr(), null()) })
}

/// What a reader's data-available listener wakes.
pub(crate) trait Wake: Send + Sync {
    /// Called from a Cyclone thread whenever data arrived (or a malformed report).
    fn wake(&self);

    /// Called from Cyclone's receive thread when `reader` has data; wakes by default.
    fn data_available(&self, reader: &Entity) {
        let _ = reader;
        self.wake();
    }
}

unsafe extern "C" fn on_data_available<W: Wake>(reader: c::dds_entity_t, arg: *mut c_void) {
    // SAFETY: arg is the Arc<W> the reader was created with, released only after the
    // reader is deleted (see ReaderHandle's Drop).
    let w = unsafe { &*(arg as *const W) };
    // Lent, never deleted here: the reader belongs to its ReaderHandle.
    let reader = std::mem::ManuallyDrop::new(Entity(reader));
    // An unwinding panic may not cross into C: it would abort the process.
    if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| w.data_available(&reader))).is_err()
    {
        tracing::error!("a data-available listener panicked; its samples were dropped");
    }
}

/// A reader with its data-available listener's argument, which it keeps alive.
pub(crate) struct ReaderHandle<W: Wake> {
    /// Deleted by hand in `Drop`, before `arg` is released.
    entity: std::mem::ManuallyDrop<Entity>,
    arg: *const W,
}

impl<W: Wake> std::fmt::Debug for ReaderHandle<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ReaderHandle")
            .field("entity", &self.entity)
            .finish()
    }
}

// SAFETY: the argument is an Arc<W> with W: Send + Sync; the handle is an integer.
unsafe impl<W: Wake> Send for ReaderHandle<W> {}
// SAFETY: as above.
unsafe impl<W: Wake> Sync for ReaderHandle<W> {}

impl<W: Wake> ReaderHandle<W> {
    /// The reader entity.
    pub(crate) fn entity(&self) -> &Entity {
        &self.entity
    }
}

impl<W: Wake> Drop for ReaderHandle<W> {
    fn drop(&mut self) {
        // SAFETY: the entity is dropped once, here. Deleting it first means no listener
        // call is running or will run when arg goes; arg came from Arc::into_raw in
        // `reader` and is released once.
        unsafe {
            std::mem::ManuallyDrop::drop(&mut self.entity);
            drop(Arc::from_raw(self.arg));
        }
    }
}

/// Creates a reader whose arriving data calls `wake.wake()`.
pub(crate) fn reader<W: Wake>(
    participant: &Entity,
    topic: TopicRef,
    qos: &Qos,
    wake: Arc<W>,
) -> Result<ReaderHandle<W>, DdsError> {
    let arg = Arc::into_raw(wake);
    let l = Listener::new(arg.cast());
    // SAFETY: l.0 is live; the callback matches; Cyclone copies the listener.
    let handle = unsafe {
        c::dds_lset_data_available(l.0, Some(on_data_available::<W>));
        c::dds_create_reader(participant.0, topic.0, qos.ptr(), l.0)
    };
    match Entity::new(handle) {
        Ok(entity) => Ok(ReaderHandle {
            entity: std::mem::ManuallyDrop::new(entity),
            arg,
        }),
        Err(e) => {
            // SAFETY: no reader holds arg; release it once.
            unsafe { drop(Arc::from_raw(arg)) };
            Err(e)
        }
    }
}

/// Writes one sample given as CDR with its 4-byte encapsulation header.
pub(crate) fn write_cdr(writer: &Entity, ty: SerType, cdr: &mut [u8]) -> Result<(), i32> {
    let iov = c::ddsrt_iovec_t {
        iov_base: cdr.as_mut_ptr().cast(),
        iov_len: cdr.len(),
    };
    // SAFETY: the iovec points at `cdr`, which outlives the call (Cyclone copies it).
    let sd = unsafe {
        c::ddsi_serdata_from_ser_iov(
            ty.0,
            c::ddsi_serdata_kind_SDK_DATA,
            1,
            &raw const iov,
            cdr.len(),
        )
    };
    if sd.is_null() {
        // The bytes do not match the topic's type.
        return Err(c::DDS_RETCODE_BAD_PARAMETER);
    }
    // SAFETY: sd is a fresh serdata of the writer's type; dds_writecdr takes the reference.
    let ret = unsafe { c::dds_writecdr(writer.0, sd) };
    if ret < 0 { Err(ret) } else { Ok(()) }
}

/// What ending an instance tells readers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Ending {
    /// The instance no longer exists (DDS dispose), and this writer forgets it.
    Dispose,
    /// This writer forgets the instance; its last value stays valid for readers.
    Unregister,
}

/// Ends one instance given as key-only CDR (with the 4-byte encapsulation header): the
/// writer drops it from its history, so late joiners no longer receive it, and matched
/// readers learn it was disposed or unregistered.
pub(crate) fn end_instance_cdr(
    writer: &Entity,
    ty: SerType,
    key_cdr: &mut [u8],
    ending: Ending,
) -> Result<(), i32> {
    let iov = c::ddsrt_iovec_t {
        iov_base: key_cdr.as_mut_ptr().cast(),
        iov_len: key_cdr.len(),
    };
    // SAFETY: the iovec points at `key_cdr`, which outlives the call (Cyclone copies it).
    let sd = unsafe {
        c::ddsi_serdata_from_ser_iov(
            ty.0,
            c::ddsi_serdata_kind_SDK_KEY,
            1,
            &raw const iov,
            key_cdr.len(),
        )
    };
    if sd.is_null() {
        return Err(c::DDS_RETCODE_BAD_PARAMETER);
    }
    let status = match ending {
        Ending::Dispose => c::DDSI_STATUSINFO_DISPOSE | c::DDSI_STATUSINFO_UNREGISTER,
        Ending::Unregister => c::DDSI_STATUSINFO_UNREGISTER,
    };
    // SAFETY: sd is a fresh serdata nobody else references yet, so setting its status and
    // time is race-free; dds_forwardcdr (unlike dds_writecdr, which clears the status)
    // sends it as it is and takes the reference. This is what dds_dispose and
    // dds_unregister_instance do after building the key serdata from a C sample.
    let ret = unsafe {
        (*sd).statusinfo = status;
        (*sd).timestamp.v = c::dds_time();
        c::dds_forwardcdr(writer.0, sd)
    };
    if ret < 0 { Err(ret) } else { Ok(()) }
}

/// Cyclone's timeout code: a reliable write blocked past its limit.
pub(crate) const TIMEOUT: i32 = c::DDS_RETCODE_TIMEOUT;

/// One sample taken from a reader: its CDR (with the encapsulation header) and metadata.
#[derive(Debug)]
pub(crate) struct Taken<'a> {
    /// CDR bytes, header included, borrowed from Cyclone's sample.
    pub(crate) cdr: &'a [u8],
    /// The writer's source timestamp, ns since the Unix epoch.
    pub(crate) source_timestamp_ns: i64,
    /// The writer's instance handle in this reader, for [`publication_guid`].
    pub(crate) publication: u64,
}

/// Takes up to `max` samples (at most 64) and hands each one with data to `each`
/// (state-only samples, such as an instance's end, are dropped, and with `skip_disposed`
/// so is the data of an instance its writer has disposed since); returns how many were
/// taken, dropped ones included, so that the caller knows the reader may hold more.
/// The bytes are lent, not copied: each sample is released when `each` returns.
pub(crate) fn take_cdr(
    reader: &Entity,
    max: usize,
    skip_disposed: bool,
    mut each: impl FnMut(Taken<'_>),
) -> Result<usize, DdsError> {
    const BATCH: usize = 64;
    let max = max.min(BATCH);
    let mut bufs = [null_mut::<c::ddsi_serdata>(); BATCH];
    // SAFETY: plain C struct, zero is a valid bit pattern.
    let mut infos: [c::dds_sample_info_t; BATCH] = unsafe { std::mem::zeroed() };
    // SAFETY: the buffers hold `max` entries.
    let n = unsafe {
        c::dds_takecdr(
            reader.0,
            bufs.as_mut_ptr(),
            u32::try_from(max).unwrap_or(1),
            infos.as_mut_ptr(),
            c::DDS_ANY_STATE,
        )
    };
    if n < 0 {
        return Err(error(n));
    }
    let n = usize::try_from(n).unwrap_or(0);
    // Released on every path out, a panic in `each` included.
    struct Release<'a>(&'a [*mut c::ddsi_serdata]);
    impl Drop for Release<'_> {
        fn drop(&mut self) {
            for sd in self.0 {
                // SAFETY: each reference dds_takecdr handed over is released once.
                unsafe { c::ddsi_serdata_unref(*sd) };
            }
        }
    }
    let _release = Release(&bufs[..n]);
    for (sd, info) in bufs.iter().zip(&infos).take(n) {
        let disposed = info.instance_state == c::dds_instance_state_DDS_IST_NOT_ALIVE_DISPOSED;
        if !info.valid_data || (skip_disposed && disposed) {
            continue;
        }
        // SAFETY: sd is a live serdata reference (released only by `_release`); the
        // serialised bytes stay valid until the matching unref below.
        unsafe {
            let size = c::ddsi_serdata_size(*sd) as usize;
            let mut iov = c::ddsrt_iovec_t {
                iov_base: null_mut(),
                iov_len: 0,
            };
            let r = c::ddsi_serdata_to_ser_ref(*sd, 0, size, &raw mut iov);
            // Unreferenced even if `each` panics.
            struct Unref(*mut c::ddsi_serdata, c::ddsrt_iovec_t);
            impl Drop for Unref {
                fn drop(&mut self) {
                    // SAFETY: the reference and iovec ddsi_serdata_to_ser_ref returned.
                    unsafe { c::ddsi_serdata_to_ser_unref(self.0, &raw const self.1) };
                }
            }
            let guard = Unref(r, iov);
            let cdr: &[u8] = if guard.1.iov_base.is_null() {
                &[]
            } else {
                std::slice::from_raw_parts(guard.1.iov_base.cast::<u8>(), guard.1.iov_len)
            };
            each(Taken {
                cdr,
                source_timestamp_ns: info.source_timestamp,
                publication: info.publication_handle,
            });
        }
    }
    Ok(n)
}

/// The GUID and partitions of a writer matched with `reader`, from its instance handle
/// there.
pub(crate) fn publication_info(reader: &Entity, publication: u64) -> Option<(Guid, Vec<String>)> {
    // SAFETY: returns null or an endpoint record that is freed below; the partition
    // strings are copied out before it is.
    unsafe {
        let ep = c::dds_get_matched_publication_data(reader.0, publication);
        if ep.is_null() {
            return None;
        }
        let g = (*ep).key.v;
        let mut partitions = Vec::new();
        let mut n: u32 = 0;
        let mut ps: *mut *mut std::os::raw::c_char = null_mut();
        if !(*ep).qos.is_null()
            && c::dds_qget_partition((*ep).qos, &raw mut n, &raw mut ps)
            && !ps.is_null()
        {
            for i in 0..n as usize {
                let p = *ps.add(i);
                if !p.is_null() {
                    partitions.push(CStr::from_ptr(p).to_string_lossy().into_owned());
                }
                c::dds_free(p.cast());
            }
            c::dds_free(ps.cast());
        }
        c::dds_builtintopic_free_endpoint(ep);
        Some((g, partitions))
    }
}

/// How many readers a writer is matched with now.
pub(crate) fn matched_readers(writer: &Entity) -> i32 {
    // SAFETY: plain C struct, zero is valid; a valid out-parameter.
    unsafe {
        let mut st: c::dds_publication_matched_status_t = std::mem::zeroed();
        if c::dds_get_publication_matched_status(writer.0, &raw mut st) < 0 {
            return 0;
        }
        i32::try_from(st.current_count).unwrap_or(i32::MAX)
    }
}

/// A change in the set of participants discovery knows.
#[derive(Debug)]
pub(crate) struct ParticipantChange {
    pub(crate) guid: Guid,
    pub(crate) name: Option<String>,
    /// False when the participant left or its lease expired.
    pub(crate) alive: bool,
}

/// A reader of the built-in participant topic.
pub(crate) fn participant_reader(participant: &Entity) -> Result<Entity, DdsError> {
    // SAFETY: the built-in topic pseudo-handle; default QoS; no listener.
    Entity::new(unsafe {
        c::dds_create_reader(
            participant.0,
            c::DDS_BUILTIN_TOPIC_DCPSPARTICIPANT,
            null(),
            null(),
        )
    })
}

/// Participants that appeared or went since the last call.
pub(crate) fn take_participants(reader: &Entity) -> Vec<ParticipantChange> {
    const MAX: usize = 32;
    let mut out = Vec::new();
    loop {
        let mut bufs = [null_mut::<c_void>(); MAX];
        // SAFETY: plain C struct, zero is valid.
        let mut infos: [c::dds_sample_info_t; MAX] = unsafe { std::mem::zeroed() };
        // SAFETY: null buffers ask Cyclone to loan the samples, returned below.
        let n = unsafe {
            c::dds_take(
                reader.0,
                bufs.as_mut_ptr(),
                infos.as_mut_ptr(),
                MAX,
                MAX as u32,
            )
        };
        if n <= 0 {
            return out;
        }
        let n = usize::try_from(n).unwrap_or(0);
        for (p, info) in bufs.iter().zip(&infos).take(n) {
            // SAFETY: the loaned samples are dds_builtintopic_participant_t records; on a
            // state-only sample only the key is filled in.
            let (guid, name) = unsafe {
                let rec = &*(*p as *const c::dds_builtintopic_participant_t);
                let mut name: *mut std::os::raw::c_char = null_mut();
                let named = info.valid_data
                    && !rec.qos.is_null()
                    && c::dds_qget_entity_name(rec.qos, &raw mut name)
                    && !name.is_null();
                let text = if named {
                    let s = CStr::from_ptr(name).to_string_lossy().into_owned();
                    c::dds_free(name.cast());
                    Some(s)
                } else {
                    None
                };
                (rec.key.v, text)
            };
            out.push(ParticipantChange {
                guid,
                name,
                alive: info.instance_state == c::dds_instance_state_DDS_IST_ALIVE,
            });
        }
        // SAFETY: returns the loan taken above.
        unsafe {
            c::dds_return_loan(reader.0, bufs.as_mut_ptr(), i32::try_from(n).unwrap_or(0));
        }
        if n < MAX {
            return out;
        }
    }
}

/// Samples Cyclone received but could not deserialise, per topic name, since start.
static MALFORMED: Mutex<Option<HashMap<String, (u64, String)>>> = Mutex::new(None);
/// Reports counted in [`MALFORMED`], over all topics: a reader compares it with the total it
/// last saw before it takes the map's lock, so the take path locks nothing while no
/// undecodable sample arrives.
static MALFORMED_TOTAL: AtomicU64 = AtomicU64::new(0);
/// Woken whenever [`MALFORMED`] changes.
static MALFORMED_WATCHERS: Mutex<Vec<std::sync::Weak<dyn Wake>>> = Mutex::new(Vec::new());

/// How many undecodable samples Cyclone dropped since the process started, on any topic.
pub(crate) fn malformed_total() -> u64 {
    MALFORMED_TOTAL.load(Ordering::Acquire)
}

/// How many samples of `topic` Cyclone dropped as undecodable since the process started.
pub(crate) fn malformed_count(topic: &str) -> u64 {
    MALFORMED
        .lock()
        .ok()
        .and_then(|m| m.as_ref().and_then(|m| m.get(topic).map(|e| e.0)))
        .unwrap_or(0)
}

/// Cyclone's last report of an undecodable sample of `topic`.
pub(crate) fn malformed_last(topic: &str) -> String {
    MALFORMED
        .lock()
        .ok()
        .and_then(|m| m.as_ref().and_then(|m| m.get(topic).map(|e| e.1.clone())))
        .unwrap_or_default()
}

/// Registers a waker for new malformed-sample reports.
pub(crate) fn watch_malformed(w: std::sync::Weak<dyn Wake>) {
    if let Ok(mut ws) = MALFORMED_WATCHERS.lock() {
        ws.retain(|w| w.strong_count() > 0);
        ws.push(w);
    }
}

/// Records a "deserialization <topic>/<type> failed" warning of Cyclone's receive path,
/// or a "dropping oversize (N > M) sample S from remote writer G <topic>/<type>" one (a
/// sample over `max_sample_bytes`, dropped before it was reassembled).
fn note_malformed(message: &str) {
    let what = if let Some(rest) = message.split(": deserialization ").nth(1) {
        rest.split(" failed").next().unwrap_or(rest)
    } else if message.contains("dropping oversize (")
        && message.contains(" from remote writer ")
        && !message.contains(" SPDP ")
    {
        match message.trim_end().rsplit_once(' ') {
            Some((_, what)) => what,
            None => return,
        }
    } else {
        return;
    };
    // "<topic>/<type>": topic names contain '/', type names do not.
    let topic = what.rsplit_once('/').map_or(what, |(t, _)| t).to_string();
    if let Ok(mut m) = MALFORMED.lock() {
        let entry = m.get_or_insert_with(HashMap::new).entry(topic).or_default();
        entry.0 += 1;
        entry.1 = message.trim().to_string();
    }
    MALFORMED_TOTAL.fetch_add(1, Ordering::Release);
    if let Ok(ws) = MALFORMED_WATCHERS.lock() {
        for w in ws.iter().filter_map(std::sync::Weak::upgrade) {
            w.wake();
        }
    }
}

unsafe extern "C" fn log_sink(_arg: *mut c_void, data: *const c::dds_log_data_t) {
    // SAFETY: Cyclone passes a valid record whose message holds `size` bytes.
    let (priority, message, full) = unsafe {
        let d = &*data;
        let bytes = std::slice::from_raw_parts(d.message.cast::<u8>(), d.size);
        // The header (time, thread) Cyclone prepends is of no use in tracing's output.
        // Some records come without the header `hdrsize` announces (the security
        // plugins'), so cut only what ends as a header does.
        let body = match bytes.split_at_checked(d.hdrsize) {
            Some((header, body)) if header.ends_with(b": ") => body,
            _ => bytes,
        };
        (
            d.priority,
            String::from_utf8_lossy(body).trim_end().to_string(),
            String::from_utf8_lossy(bytes),
        )
    };
    if message.is_empty() {
        return;
    }
    // Matched on the whole record: some records (the oversize drop) come without the
    // header `hdrsize` announces, so the body alone would lose their start.
    if full.contains(": deserialization ") || full.contains("dropping oversize (") {
        note_malformed(&full);
    }
    crate::omg::note_handshake(&full);
    // A remote participant can make Cyclone warn at will (a handshake refused per
    // attempt): past the budget its lines go to debug, after being counted above.
    let budget = match priority {
        c::DDS_LC_FATAL | c::DDS_LC_ERROR | c::DDS_LC_WARNING => CYCLONE_LOG
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take(std::time::Instant::now()),
        _ => None,
    };
    match (priority, budget) {
        (_, None) => tracing::debug!(target: "cyclonedds", "{message}"),
        (c::DDS_LC_FATAL | c::DDS_LC_ERROR, Some(0)) => {
            tracing::error!(target: "cyclonedds", "{message}");
        }
        (c::DDS_LC_FATAL | c::DDS_LC_ERROR, Some(left_out)) => {
            tracing::error!(target: "cyclonedds", left_out, "{message} (and {left_out} earlier lines not logged)");
        }
        (_, Some(0)) => tracing::warn!(target: "cyclonedds", "{message}"),
        (_, Some(left_out)) => {
            tracing::warn!(target: "cyclonedds", left_out, "{message} (and {left_out} earlier lines not logged)");
        }
    }
}

/// Warnings and errors Cyclone may log a second; the rest are counted where they matter
/// (refused handshakes, malformed samples) and logged at debug level.
static CYCLONE_LOG: Mutex<crate::LogBudget> = Mutex::new(crate::LogBudget::new(20));

fn install_log_sink() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // SAFETY: a static callback without state.
        unsafe {
            c::dds_set_log_mask(c::DDS_LC_FATAL | c::DDS_LC_ERROR | c::DDS_LC_WARNING);
            c::dds_set_log_sink(Some(log_sink), null_mut());
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_deserialization_warning_is_counted_against_its_topic() {
        let before = malformed_count("test/malformed/topic");
        note_malformed(
            "1611:f8f44b0f:ce8e6612:2 #1: deserialization test/malformed/topic/shoal::StateVector failed (for reasons unknown)",
        );
        let (count, last) = (
            malformed_count("test/malformed/topic"),
            malformed_last("test/malformed/topic"),
        );
        assert_eq!(count, before + 1);
        assert!(last.contains("#1"), "{last}");
        // Other warnings are not counted.
        note_malformed("something else entirely");
        // An oversize sample dropped before reassembly counts against its topic too.
        note_malformed(
            "dropping oversize (10485808 > 65536) sample 3 from remote writer \
             1611f8f4:4b0fce8e:66120000:102 test/malformed/topic/shoal::StateVector",
        );
        assert_eq!(malformed_count("test/malformed/topic"), before + 2);
        // Oversize discovery names no topic: not counted against one.
        note_malformed("dropping oversize (70000 > 65536) SPDP sample 1 from remote writer x");
        assert_eq!(malformed_count("test/malformed/topic"), before + 2);
        assert_eq!(malformed_count("x"), 0);
    }

    /// Cyclone has one configuration per domain and process: a second, different one is
    /// refused with a message, the first stays usable.
    #[test]
    fn a_second_configuration_for_an_open_domain_is_refused() {
        let first = DdsConfig {
            domain_id: 212,
            ..DdsConfig::default()
        };
        assert_eq!(domain(&first), Ok(()));
        assert_eq!(domain(&first), Ok(()));
        let other = DdsConfig {
            socket_receive_buffer: 1 << 20,
            ..first
        };
        let err = domain(&other)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.contains("domain 212 is already open"), "{err}");
    }

    #[test]
    fn the_domain_configuration_confines_dds_to_the_configured_interfaces() {
        let xml = domain_xml(&DdsConfig::default());
        assert!(xml.contains(r#"<NetworkInterface address="127.0.0.1" multicast="true"/>"#));
        assert!(xml.contains("<AllowMulticast>spdp</AllowMulticast>"));
        let c = DdsConfig {
            interfaces: vec![std::net::Ipv4Addr::new(10, 1, 2, 3).into()],
            ..DdsConfig::default()
        };
        assert!(domain_xml(&c).contains(r#"address="10.1.2.3" multicast="default""#));
    }
}
