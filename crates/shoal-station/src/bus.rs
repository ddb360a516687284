//! The station core's seam to the bus: what it publishes goes through an [`Outbox`], what
//! it hears arrives as calls on the handle. The Publish/Subscribe Manager is one outbox
//! ([`DdsOutbox`]); tests use another, so the core runs without Cyclone or a network.

use shoal_dds::{Priority, PubSub, TopicType, WriteError, Writer, WriterOptions};
use shoal_model::{Event, Severity, TaskAssignment, TaskKind};

/// A sample the bus would not take.
#[derive(Debug, thiserror::Error)]
#[error("{topic} not published: {source}")]
pub struct PublishError {
    /// The topic it was for.
    pub topic: &'static str,
    /// What the bus said.
    #[source]
    pub source: Box<dyn std::error::Error + Send + Sync>,
}

impl PublishError {
    /// An error for `topic` from whatever the bus reported.
    pub fn new(
        topic: &'static str,
        source: impl Into<Box<dyn std::error::Error + Send + Sync>>,
    ) -> Self {
        Self {
            topic,
            source: source.into(),
        }
    }
}

/// What the station core sends to vehicles and to other listeners on the bus.
///
/// Implementations choose the priority class: aborts and alarms are emergencies.
pub trait Outbox: Send + Sync + std::fmt::Debug {
    /// Publishes a task assignment; returns once the bus has it.
    fn publish_task(&self, task: TaskAssignment) -> Result<(), PublishError>;
    /// Ends a published task's instance once the task has ended (DDS dispose), so the bus
    /// no longer hands it to a vehicle that joins or restarts later.
    fn retire_task(&self, task: &TaskAssignment) -> Result<(), PublishError>;
    /// Publishes an event the station raised (its own or a rule's).
    fn publish_event(&self, event: Event) -> Result<(), PublishError>;
    /// Remote readers of tasks matched now (a console shows whether anyone listens).
    fn task_readers(&self) -> i32;
}

/// Where an event the station records came from; decides where it goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventOrigin {
    /// The station itself (contact, tasks, rejections, operators' actions).
    Station,
    /// A rule of the semantic model fired: the model holds it already.
    Rule,
}

/// The station's DDS writers, one per priority class and topic.
#[derive(Debug)]
pub struct DdsOutbox {
    task: Writer<TaskAssignment>,
    abort: Writer<TaskAssignment>,
    event: Writer<Event>,
    alarm: Writer<Event>,
}

impl DdsOutbox {
    /// Creates the writers on `dds`.
    pub fn new(dds: &PubSub) -> Result<Self, shoal_dds::CreateError> {
        let control = WriterOptions::new(Priority::Control);
        let emergency = WriterOptions::new(Priority::Emergency);
        Ok(Self {
            task: dds.writer(control)?,
            abort: dds.writer(emergency)?,
            event: dds.writer(control)?,
            alarm: dds.writer(emergency)?,
        })
    }
}

fn published<T: TopicType>(r: Result<(), WriteError<T>>) -> Result<(), PublishError> {
    r.map_err(|e| PublishError::new(T::TOPIC, e.to_string()))
}

impl Outbox for DdsOutbox {
    fn publish_task(&self, task: TaskAssignment) -> Result<(), PublishError> {
        let writer = if task.kind == TaskKind::Abort {
            &self.abort
        } else {
            &self.task
        };
        published(writer.write_blocking(task))
    }

    fn retire_task(&self, task: &TaskAssignment) -> Result<(), PublishError> {
        let writer = if task.kind == TaskKind::Abort {
            &self.abort
        } else {
            &self.task
        };
        writer
            .dispose(task)
            .map_err(|e| PublishError::new(TaskAssignment::TOPIC, e))
    }

    fn publish_event(&self, event: Event) -> Result<(), PublishError> {
        let writer = if event.severity >= Severity::Alarm {
            &self.alarm
        } else {
            &self.event
        };
        published(writer.write_blocking(event))
    }

    fn task_readers(&self) -> i32 {
        self.task.matched_readers()
    }
}
