//! The DICOM C-STORE and C-ECHO service class provider (`serve --dicom-port`):
//! a modality, a workstation or a PACS routing rule pushes instances over a
//! DICOM association (the upper layer of PS3.8 through `dicom-ul`, the DIMSE
//! messages of PS3.7 §9.3) and they land where STOW-RS instances do
//! ([`crate::receive`]): kept series by series, each bricked and served once
//! it has settled.
//!
//! Who may associate: the called AE title must be this server's
//! (`--ae-title`) and the calling AE title one of `--dicom-allow` (`*`:
//! any); other requests are rejected (A-ASSOCIATE-RJ, permanent, naming the
//! title that was not recognised) and audited. Any storage SOP class and any
//! transfer syntax this build decodes is accepted; instances that turn out
//! not to be part of a volume (a localizer, a report) are kept, and their
//! series is logged as not offered when it fails to brick.
//!
//! Bounds: [`MAX_ASSOCIATIONS`] at once (more wait [`ASSOCIATION_WAIT`],
//! then are rejected as transient, local limit exceeded); PDUs of at most
//! [`MAX_PDU`] bytes; [`PDU_TIMEOUT`] for the peer's next PDU; command sets
//! of at most [`MAX_COMMAND_BYTES`]; instances of at most
//! [`crate::receive::MAX_INSTANCE_BYTES`], streamed to disk as they come.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::InMemDicomObject;
use dicom_transfer_syntax_registry::entries::IMPLICIT_VR_LITTLE_ENDIAN;
use dicom_ul::association::server::AccessControl;
use dicom_ul::pdu::{
    AbortRQServiceProviderReason, AbortRQSource, AssociationRJ, AssociationRJResult,
    AssociationRJServiceProviderPresentationReason, AssociationRJServiceUserReason,
    AssociationRJSource, PDataValue, PDataValueType, PresentationContextResultReason, UserIdentity,
};
use dicom_ul::{Pdu, ServerAssociationOptions};
use tokio::io::AsyncWriteExt as _;
use tokio::net::{TcpListener, TcpStream};
use tokio_util::sync::CancellationToken;

use crate::audit::{Audit, Event, Outcome};
use crate::receive::{Claimed, Receiver};

/// Most associations served at once.
pub const MAX_ASSOCIATIONS: usize = 16;
/// How long an association over [`MAX_ASSOCIATIONS`] waits for a place
/// before it is rejected.
pub const ASSOCIATION_WAIT: Duration = Duration::from_secs(10);
/// Longest wait for the peer's next PDU (and for a PDU to be sent).
pub const PDU_TIMEOUT: Duration = Duration::from_secs(60);
/// Largest PDU the peer may send (our maximum length, told at association).
pub const MAX_PDU: u32 = 256 * 1024;
/// Most bytes of one DIMSE command set.
pub const MAX_COMMAND_BYTES: usize = 64 * 1024;

/// Command fields (PS3.7 §E.1).
const C_STORE_RQ: u16 = 0x0001;
const C_STORE_RSP: u16 = 0x8001;
const C_ECHO_RQ: u16 = 0x0030;
const C_ECHO_RSP: u16 = 0x8030;
/// CommandDataSetType: no data set follows.
const NO_DATA_SET: u16 = 0x0101;

/// Statuses (PS3.7 Annex C, PS3.4 §B.2.3).
const SUCCESS: u16 = 0x0000;
const UNRECOGNIZED_OPERATION: u16 = 0x0211;
const OUT_OF_RESOURCES: u16 = 0xA700;
const DATA_SET_DOES_NOT_MATCH: u16 = 0xA900;
const CANNOT_UNDERSTAND: u16 = 0xC000;

/// Who may associate.
#[derive(Debug, Clone)]
pub struct DicomSettings {
    /// This server's AE title, which associations must call.
    pub ae_title: String,
    /// Calling AE titles allowed; `*` among them allows any.
    pub callers: Vec<String>,
}

impl DicomSettings {
    fn allows(&self, caller: &str) -> bool {
        self.callers.iter().any(|c| c == "*" || c == caller)
    }
}

/// An AE title given on the command line (`--ae-title`, `--dicom-allow`):
/// 1 to 16 characters of the default repertoire, no backslash, not only
/// spaces (leading and trailing spaces are not significant, PS3.5 §6.2).
///
/// # Errors
/// What is wrong with it, and what was expected.
pub fn parse_ae_title(text: &str) -> Result<String, String> {
    let title = text.trim_matches(' ');
    if title.is_empty() {
        return Err("empty: expected 1 to 16 characters".into());
    }
    if title.len() > 16 {
        return Err(format!(
            "{} characters: expected at most 16",
            title.chars().count()
        ));
    }
    if let Some(c) = title
        .chars()
        .find(|c| !c.is_ascii() || c.is_ascii_control() || *c == '\\')
    {
        return Err(format!(
            "{c:?}: expected printable ASCII characters other than backslash"
        ));
    }
    Ok(title.to_owned())
}

/// `--dicom-allow`: an AE title, or `*` for any.
///
/// # Errors
/// As [`parse_ae_title`].
pub fn parse_caller(text: &str) -> Result<String, String> {
    if text.trim() == "*" {
        return Ok("*".into());
    }
    parse_ae_title(text)
}

/// Serves DICOM associations arriving on `listener` until `shutdown`,
/// keeping the instances they store with `receiver`.
pub fn spawn(
    listener: TcpListener,
    settings: DicomSettings,
    receiver: Arc<Receiver>,
    audit: Arc<Audit>,
    shutdown: CancellationToken,
) {
    let places = Arc::new(tokio::sync::Semaphore::new(MAX_ASSOCIATIONS));
    let settings = Arc::new(settings);
    tokio::spawn(async move {
        loop {
            let (socket, peer) = tokio::select! {
                () = shutdown.cancelled() => return,
                accepted = listener.accept() => match accepted {
                    Ok(accepted) => accepted,
                    Err(e) => {
                        // Out of file descriptors, say: try again shortly.
                        tracing::warn!("DICOM: cannot accept a connection: {e}");
                        tokio::time::sleep(Duration::from_millis(100)).await;
                        continue;
                    }
                },
            };
            let peer_state = Peer {
                settings: Arc::clone(&settings),
                receiver: Arc::clone(&receiver),
                audit: Arc::clone(&audit),
                address: peer,
            };
            let places = Arc::clone(&places);
            let shutdown = shutdown.clone();
            tokio::spawn(async move {
                let Ok(Ok(place)) =
                    tokio::time::timeout(ASSOCIATION_WAIT, places.acquire_owned()).await
                else {
                    tracing::warn!(
                        "DICOM: association from {peer} rejected: {MAX_ASSOCIATIONS} associations already open"
                    );
                    reject_busy(socket).await;
                    return;
                };
                tokio::select! {
                    () = shutdown.cancelled() => {}
                    () = peer_state.serve(socket) => {}
                }
                drop(place);
            });
        }
    });
}

/// A-ASSOCIATE-RJ (transient, local limit exceeded) on `socket`, then
/// closes it.
async fn reject_busy(mut socket: TcpStream) {
    let mut bytes = Vec::new();
    let pdu = Pdu::AssociationRJ(AssociationRJ {
        result: AssociationRJResult::Transient,
        source: AssociationRJSource::ServiceProviderPresentation(
            AssociationRJServiceProviderPresentationReason::LocalLimitExceeded,
        ),
    });
    if dicom_ul::write_pdu(&mut bytes, &pdu).is_ok() {
        let _ = tokio::time::timeout(Duration::from_secs(5), socket.write_all(&bytes)).await;
    }
    let _ = socket.shutdown().await;
}

/// The access rule of one association request: remembers why it refused.
struct Access {
    settings: Arc<DicomSettings>,
    refused: Arc<Mutex<Option<String>>>,
}

impl AccessControl for Access {
    fn check_access(
        &self,
        this_ae_title: &str,
        calling_ae_title: &str,
        called_ae_title: &str,
        _user_identity: Option<&UserIdentity>,
    ) -> Result<(), AssociationRJServiceUserReason> {
        let calling = calling_ae_title.trim_matches(' ');
        let called = called_ae_title.trim_matches(' ');
        let why = if called != this_ae_title.trim_matches(' ') {
            Some((
                format!("called AE title {called:?}: expected {this_ae_title:?}"),
                AssociationRJServiceUserReason::CalledAETitleNotRecognized,
            ))
        } else if !self.settings.allows(calling) {
            Some((
                format!("calling AE title {calling:?} is not one --dicom-allow names"),
                AssociationRJServiceUserReason::CallingAETitleNotRecognized,
            ))
        } else {
            None
        };
        match why {
            None => Ok(()),
            Some((why, reason)) => {
                *self.refused.lock().unwrap_or_else(PoisonError::into_inner) = Some(why);
                Err(reason)
            }
        }
    }
}

/// One connection's context.
struct Peer {
    settings: Arc<DicomSettings>,
    receiver: Arc<Receiver>,
    audit: Arc<Audit>,
    address: SocketAddr,
}

/// A DIMSE command set's fields that matter here.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Command {
    /// CommandField (e.g. 0x0001 C-STORE-RQ, 0x0030 C-ECHO-RQ).
    pub field: u16,
    /// MessageID.
    pub message_id: u16,
    /// Whether a data set follows (CommandDataSetType other than 0x0101).
    pub has_data_set: bool,
    /// AffectedSOPClassUID ("" when absent).
    pub class: String,
    /// AffectedSOPInstanceUID ("" when absent).
    pub instance: String,
}

/// What the association expects next.
enum Expect {
    /// A command (the bytes of its fragments so far).
    Command(Vec<u8>),
    /// The data set of `command`, streamed to `file` (or dropped when the
    /// instance was refused before its data came: `failure`).
    Data {
        command: Command,
        context: u8,
        file: Option<Box<(tempfile::NamedTempFile, tokio::fs::File)>>,
        bytes: u64,
        failure: Option<(u16, String)>,
    },
}

/// How an association went.
#[derive(Default)]
struct Tally {
    stored: usize,
    refused: usize,
    series: std::collections::BTreeSet<String>,
}

impl Peer {
    async fn serve(self, socket: TcpStream) {
        let refused = Arc::new(Mutex::new(None));
        let options = ServerAssociationOptions::new()
            .ae_access_control(Access {
                settings: Arc::clone(&self.settings),
                refused: Arc::clone(&refused),
            })
            .ae_title(self.settings.ae_title.clone())
            .with_abstract_syntax(uids::VERIFICATION)
            .promiscuous(true)
            .max_pdu_length(MAX_PDU)
            .read_timeout(PDU_TIMEOUT)
            .write_timeout(PDU_TIMEOUT);
        let mut association = match options.establish_async(socket).await {
            Ok(association) => association,
            Err(e) => {
                let why = refused
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .take();
                if let Some(why) = why {
                    tracing::warn!("DICOM: association from {} rejected: {why}", self.address);
                    self.audit.record(
                        &Event::new("associate", None, Some(self.address.ip()), Outcome::Denied)
                            .detail(why),
                    );
                } else {
                    tracing::warn!(
                        "DICOM: no association with {}: {}",
                        self.address,
                        snafu_chain(&e)
                    );
                }
                return;
            }
        };
        let caller = dicom_ul::association::Association::peer_ae_title(&association)
            .trim_matches(' ')
            .to_owned();
        let contexts: Vec<(u8, String)> = association
            .presentation_contexts()
            .iter()
            .filter(|c| c.reason == PresentationContextResultReason::Acceptance)
            .map(|c| (c.id, c.transfer_syntax.trim_end_matches('\0').to_owned()))
            .collect();
        tracing::info!(
            "DICOM: association from {caller} at {} ({} presentation context(s) accepted)",
            self.address,
            contexts.len()
        );
        let mut tally = Tally::default();
        let ended = self
            .converse(&mut association, &caller, &contexts, &mut tally)
            .await;
        match &ended {
            Ok(()) => {
                let _ = association.send(&Pdu::ReleaseRP).await;
            }
            Err((why, abort)) => {
                tracing::warn!(
                    "DICOM: association from {caller} at {} ended: {why}",
                    self.address
                );
                if *abort {
                    let _ = association
                        .send(&Pdu::AbortRQ {
                            source: AbortRQSource::ServiceProvider(
                                AbortRQServiceProviderReason::UnexpectedPdu,
                            ),
                        })
                        .await;
                }
            }
        }
        let outcome = match (tally.stored, tally.refused, &ended) {
            (_, 0, Ok(())) => Outcome::Success,
            (0, _, _) if tally.refused > 0 => Outcome::Denied,
            _ => Outcome::Failure,
        };
        if tally.stored + tally.refused > 0 || ended.is_err() {
            let mut event =
                Event::new("store", None, Some(self.address.ip()), outcome).detail(format!(
                    "DICOM association from AE {caller}: {} instance(s) stored, {} refused{}",
                    tally.stored,
                    tally.refused,
                    ended
                        .as_ref()
                        .err()
                        .map(|(why, _)| format!("; ended: {why}"))
                        .unwrap_or_default()
                ));
            event.user = Some(format!("AE {caller}"));
            self.audit.record(&event);
        }
        tracing::info!(
            "DICOM: association from {caller} closed: {} instance(s) stored in {} series, {} refused",
            tally.stored,
            tally.series.len(),
            tally.refused
        );
    }

    /// Answers the association's requests until it is released (`Ok`) or
    /// broken (`Err` with why, and whether to abort it).
    async fn converse(
        &self,
        association: &mut dicom_ul::association::server::AsyncServerAssociation<TcpStream>,
        caller: &str,
        contexts: &[(u8, String)],
        tally: &mut Tally,
    ) -> Result<(), (String, bool)> {
        let mut expect = Expect::Command(Vec::new());
        loop {
            let pdu = association
                .receive()
                .await
                .map_err(|e| (format!("receiving: {}", snafu_chain(&e)), true))?;
            let values = match pdu {
                Pdu::PData { data } => data,
                Pdu::ReleaseRQ => {
                    return match expect {
                        Expect::Command(ref c) if c.is_empty() => Ok(()),
                        _ => Err((
                            "released in the middle of a message: the instance is dropped".into(),
                            false,
                        )),
                    };
                }
                Pdu::AbortRQ { source } => {
                    return Err((format!("aborted by the peer ({source:?})"), false));
                }
                other => {
                    return Err((
                        format!("{}: expected P-DATA or A-RELEASE", pdu_name(&other)),
                        true,
                    ));
                }
            };
            for value in values {
                let PDataValue {
                    presentation_context_id: id,
                    value_type,
                    is_last,
                    data,
                } = value;
                let Some((_, transfer_syntax)) = contexts.iter().find(|(c, _)| *c == id) else {
                    return Err((
                        format!("P-DATA on presentation context {id}, which was not accepted"),
                        true,
                    ));
                };
                match (&mut expect, value_type) {
                    (Expect::Command(bytes), PDataValueType::Command) => {
                        if bytes.len() + data.len() > MAX_COMMAND_BYTES {
                            return Err((
                                format!(
                                    "a command set over {MAX_COMMAND_BYTES} bytes: expected a DIMSE command"
                                ),
                                true,
                            ));
                        }
                        bytes.extend_from_slice(&data);
                        if !is_last {
                            continue;
                        }
                        let command = parse_command(bytes).map_err(|e| (e, true))?;
                        if command.has_data_set {
                            expect = self.expect_data(command, id, transfer_syntax, caller);
                        } else {
                            self.answer(association, id, &command, None, tally).await?;
                            expect = Expect::Command(Vec::new());
                        }
                    }
                    (
                        Expect::Data {
                            context,
                            file,
                            bytes,
                            failure,
                            ..
                        },
                        PDataValueType::Data,
                    ) => {
                        if id != *context {
                            return Err((
                                format!(
                                    "a data set fragment on presentation context {id}: expected {context}, the command's"
                                ),
                                true,
                            ));
                        }
                        *bytes += data.len() as u64;
                        if failure.is_none() && *bytes > crate::receive::MAX_INSTANCE_BYTES {
                            *failure = Some((
                                OUT_OF_RESOURCES,
                                format!(
                                    "over {} bytes: expected an instance of at most that",
                                    crate::receive::MAX_INSTANCE_BYTES
                                ),
                            ));
                            *file = None;
                        }
                        if failure.is_none()
                            && let Some(opened) = file
                            && let (_, writer) = &mut **opened
                            && let Err(e) = writer.write_all(&data).await
                        {
                            *failure = Some((OUT_OF_RESOURCES, format!("cannot write it: {e}")));
                            *file = None;
                        }
                        if !is_last {
                            continue;
                        }
                        let Expect::Data {
                            command,
                            file,
                            failure,
                            ..
                        } = std::mem::replace(&mut expect, Expect::Command(Vec::new()))
                        else {
                            unreachable!("matched above");
                        };
                        let failure = match (failure, file) {
                            (Some(failure), _) => Some(failure),
                            (None, Some(opened)) => {
                                let (file, writer) = *opened;
                                self.keep(&command, file, writer, tally).await.err()
                            }
                            (None, None) => Some((CANNOT_UNDERSTAND, "no data set".into())),
                        };
                        if let Some((_, why)) = &failure {
                            tally.refused += 1;
                            tracing::warn!(
                                "DICOM: instance {} from {caller} refused: {why}",
                                command.instance
                            );
                        }
                        self.answer(association, id, &command, failure, tally)
                            .await?;
                    }
                    (Expect::Command(_), PDataValueType::Data) => {
                        return Err((
                            "a data set fragment before its command: expected a command".into(),
                            true,
                        ));
                    }
                    (Expect::Data { .. }, PDataValueType::Command) => {
                        return Err((
                            "a command fragment before the last data set fragment: expected the rest of the data set".into(),
                            true,
                        ));
                    }
                }
            }
        }
    }

    /// What to do with the data set that follows `command`, which came on
    /// presentation context `context` of `transfer_syntax`: a C-STORE's is
    /// written to a file with its file meta information; any other is
    /// read and dropped.
    fn expect_data(
        &self,
        command: Command,
        context: u8,
        transfer_syntax: &str,
        caller: &str,
    ) -> Expect {
        let mut failure = None;
        let mut file = None;
        if command.field != C_STORE_RQ {
            failure = Some((
                UNRECOGNIZED_OPERATION,
                format!("command 0x{:04X}", command.field),
            ));
        } else if !blocks::ingest::dicom::is_uid(&command.class)
            || !blocks::ingest::dicom::is_uid(&command.instance)
        {
            failure = Some((
                CANNOT_UNDERSTAND,
                format!(
                    "AffectedSOPClassUID {:?}, AffectedSOPInstanceUID {:?}: expected UIDs",
                    command.class, command.instance
                ),
            ));
        } else if let Some(why) = self.receiver.full() {
            failure = Some((OUT_OF_RESOURCES, why));
        } else {
            match self.start_file(&command, transfer_syntax, caller) {
                Ok(opened) => file = Some(Box::new(opened)),
                Err(e) => failure = Some((OUT_OF_RESOURCES, format!("cannot make a file: {e}"))),
            }
        }
        Expect::Data {
            command,
            context,
            file,
            bytes: 0,
            failure,
        }
    }

    /// A file in the receiver's `incoming/` holding the preamble and file
    /// meta information of the instance `command` stores, ready for its
    /// data set.
    fn start_file(
        &self,
        command: &Command,
        transfer_syntax: &str,
        caller: &str,
    ) -> std::io::Result<(tempfile::NamedTempFile, tokio::fs::File)> {
        use std::io::Write as _;
        let meta = dicom_object::meta::FileMetaTableBuilder::new()
            .media_storage_sop_class_uid(command.class.as_str())
            .media_storage_sop_instance_uid(command.instance.as_str())
            .transfer_syntax(transfer_syntax)
            .source_application_entity_title(caller)
            .receiving_application_entity_title(self.settings.ae_title.as_str())
            .build()
            .map_err(std::io::Error::other)?;
        let mut file = self.receiver.incoming_file()?;
        file.write_all(&[0; 128])?;
        file.write_all(b"DICM")?;
        meta.write(&mut file).map_err(std::io::Error::other)?;
        file.flush()?;
        let writer = tokio::fs::File::from_std(file.as_file().try_clone()?);
        Ok((file, writer))
    }

    /// Keeps a received instance, checking it is what its command said.
    async fn keep(
        &self,
        command: &Command,
        file: tempfile::NamedTempFile,
        mut writer: tokio::fs::File,
        tally: &mut Tally,
    ) -> Result<(), (u16, String)> {
        writer
            .flush()
            .await
            .map_err(|e| (OUT_OF_RESOURCES, format!("cannot write it: {e}")))?;
        drop(writer);
        let receiver = Arc::clone(&self.receiver);
        let (class, instance) = (command.class.clone(), command.instance.clone());
        let kept = tokio::task::spawn_blocking(move || {
            receiver.keep(
                file,
                &Claimed {
                    study: None,
                    class: Some(&class),
                    instance: Some(&instance),
                },
            )
        })
        .await
        .map_err(|e| (OUT_OF_RESOURCES, e.to_string()))?;
        match (kept.failure, kept.series) {
            (None, Some(series)) => {
                tally.stored += 1;
                tally.series.insert(series);
                Ok(())
            }
            (Some(why), _) if kept.mismatch => Err((DATA_SET_DOES_NOT_MATCH, why)),
            (Some(why), _) if kept.full => Err((OUT_OF_RESOURCES, why)),
            (why, _) => Err((CANNOT_UNDERSTAND, why.unwrap_or_default())),
        }
    }

    /// Sends the response to `command` on presentation context `context`:
    /// C-ECHO and C-STORE answered with `failure` or success, anything else
    /// as an unrecognised operation.
    async fn answer(
        &self,
        association: &mut dicom_ul::association::server::AsyncServerAssociation<TcpStream>,
        context: u8,
        command: &Command,
        failure: Option<(u16, String)>,
        tally: &mut Tally,
    ) -> Result<(), (String, bool)> {
        let (field, failure) = match command.field {
            C_ECHO_RQ => (C_ECHO_RSP, failure),
            C_STORE_RQ => (C_STORE_RSP, failure),
            other => {
                tally.refused += usize::from(command.has_data_set);
                (
                    other | 0x8000,
                    Some((
                        UNRECOGNIZED_OPERATION,
                        format!("command 0x{other:04X}: voxserve answers C-ECHO and C-STORE"),
                    )),
                )
            }
        };
        let class = if command.field == C_ECHO_RQ && command.class.is_empty() {
            uids::VERIFICATION.to_owned()
        } else {
            command.class.clone()
        };
        let (status, comment) = failure.unwrap_or((SUCCESS, String::new()));
        let mut elements = vec![
            DataElement::new(
                tags::AFFECTED_SOP_CLASS_UID,
                VR::UI,
                PrimitiveValue::from(class),
            ),
            DataElement::new(tags::COMMAND_FIELD, VR::US, PrimitiveValue::from(field)),
            DataElement::new(
                tags::MESSAGE_ID_BEING_RESPONDED_TO,
                VR::US,
                PrimitiveValue::from(command.message_id),
            ),
            DataElement::new(
                tags::COMMAND_DATA_SET_TYPE,
                VR::US,
                PrimitiveValue::from(NO_DATA_SET),
            ),
            DataElement::new(tags::STATUS, VR::US, PrimitiveValue::from(status)),
        ];
        if !command.instance.is_empty() {
            elements.push(DataElement::new(
                tags::AFFECTED_SOP_INSTANCE_UID,
                VR::UI,
                PrimitiveValue::from(command.instance.clone()),
            ));
        }
        if status != SUCCESS {
            // ErrorComment is an LO: at most 64 characters.
            let comment: String = comment.chars().take(64).collect();
            elements.push(DataElement::new(
                tags::ERROR_COMMENT,
                VR::LO,
                PrimitiveValue::from(comment),
            ));
        }
        let data = command_bytes(elements).map_err(|e| (e, true))?;
        association
            .send(&Pdu::PData {
                data: vec![PDataValue {
                    presentation_context_id: context,
                    value_type: PDataValueType::Command,
                    is_last: true,
                    data,
                }],
            })
            .await
            .map_err(|e| (format!("sending a response: {}", snafu_chain(&e)), false))
    }
}

/// Reads a command set (implicit VR little endian, PS3.7 §6.3.1), as a
/// peer sent it. Read here rather than by a general DICOM parser: a command
/// set is a flat list of group 0000 elements, and each length is checked
/// against the bytes there are (a parser would trust a length, or a VR's
/// size over the length given, and reserve or skip that much).
///
/// # Errors
/// What is missing or malformed, and what was expected.
pub fn parse_command(bytes: &[u8]) -> Result<Command, String> {
    let mut elements: Vec<(u16, &[u8])> = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let Some(head) = bytes.get(at..at + 8) else {
            return Err(
                "a command set cut short within an element's header: expected a DIMSE command"
                    .into(),
            );
        };
        let group = u16::from_le_bytes([head[0], head[1]]);
        let element = u16::from_le_bytes([head[2], head[3]]);
        let length = u32::from_le_bytes([head[4], head[5], head[6], head[7]]) as usize;
        if group != 0 {
            return Err(format!(
                "element ({group:04X},{element:04X}) in a command set: expected command elements (group 0000) only"
            ));
        }
        let rest = bytes.len() - at - 8;
        if length > rest {
            return Err(format!(
                "element (0000,{element:04X}) of {length} bytes where {rest} remain: expected a whole DIMSE command"
            ));
        }
        elements.push((element, &bytes[at + 8..at + 8 + length]));
        at += 8 + length;
    }
    let value = |element: u16| {
        elements
            .iter()
            .find(|(e, _)| *e == element)
            .map(|(_, v)| *v)
    };
    let number = |element: u16, name: &str| -> Result<u16, String> {
        match value(element) {
            Some(&[a, b]) => Ok(u16::from_le_bytes([a, b])),
            Some(v) => Err(format!(
                "{name} (0000,{element:04X}) of {} bytes: expected 2 (US)",
                v.len()
            )),
            None => Err(format!(
                "a command without {name}: expected a DIMSE command"
            )),
        }
    };
    let uid = |element: u16, name: &str| -> Result<String, String> {
        let Some(v) = value(element) else {
            return Ok(String::new());
        };
        let text = std::str::from_utf8(v)
            .ok()
            .map(|t| t.trim_end_matches(['\0', ' ']))
            .filter(|t| t.len() <= 64 && t.bytes().all(|b| b.is_ascii_digit() || b == b'.'))
            .ok_or_else(|| format!("{name} (0000,{element:04X}): expected a UID"))?;
        Ok(text.to_owned())
    };
    let field = number(0x0100, "CommandField")?;
    let message_id = match number(0x0110, "MessageID") {
        Ok(id) => id,
        Err(e) if field == C_ECHO_RQ || field == C_STORE_RQ => return Err(e),
        Err(_) => 0,
    };
    Ok(Command {
        field,
        message_id,
        has_data_set: number(0x0800, "CommandDataSetType")? != NO_DATA_SET,
        class: uid(0x0002, "AffectedSOPClassUID")?,
        instance: uid(0x1000, "AffectedSOPInstanceUID")?,
    })
}

/// A command set's bytes: CommandGroupLength, then `elements`, implicit VR
/// little endian.
fn command_bytes(elements: Vec<DataElement<InMemDicomObject>>) -> Result<Vec<u8>, String> {
    let object = InMemDicomObject::from_element_iter(elements);
    let mut body = Vec::new();
    object
        .write_dataset_with_ts(&mut body, &IMPLICIT_VR_LITTLE_ENDIAN.erased())
        .map_err(|e| format!("encoding a response: {e}"))?;
    let length = u32::try_from(body.len()).map_err(|e| e.to_string())?;
    // (0000,0000) UL, 4 bytes: the length of what follows.
    let mut bytes = vec![0, 0, 0, 0, 4, 0, 0, 0];
    bytes.extend_from_slice(&length.to_le_bytes());
    bytes.extend_from_slice(&body);
    Ok(bytes)
}

/// A PDU's name, for errors.
fn pdu_name(pdu: &Pdu) -> &'static str {
    match pdu {
        Pdu::AssociationRQ(_) => "A-ASSOCIATE-RQ",
        Pdu::AssociationAC(_) => "A-ASSOCIATE-AC",
        Pdu::AssociationRJ(_) => "A-ASSOCIATE-RJ",
        Pdu::PData { .. } => "P-DATA-TF",
        Pdu::ReleaseRQ => "A-RELEASE-RQ",
        Pdu::ReleaseRP => "A-RELEASE-RP",
        Pdu::AbortRQ { .. } => "A-ABORT",
        Pdu::Unknown { .. } => "an unknown PDU",
    }
}

/// An error with its sources, one line.
fn snafu_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ae_titles_are_checked() {
        assert_eq!(parse_ae_title(" CT1 ").as_deref(), Ok("CT1"));
        assert!(parse_ae_title("").is_err());
        assert!(parse_ae_title("    ").is_err());
        assert!(parse_ae_title("SEVENTEEN_LETTERS").is_err());
        assert!(parse_ae_title("A\\B").is_err());
        assert!(parse_ae_title("A\tB").is_err());
        assert!(parse_ae_title("É").is_err());
        assert_eq!(parse_caller("*").as_deref(), Ok("*"));
    }

    #[test]
    fn a_response_reads_back_as_the_command_it_answers() {
        let bytes = command_bytes(vec![
            DataElement::new(
                tags::AFFECTED_SOP_CLASS_UID,
                VR::UI,
                PrimitiveValue::from(uids::CT_IMAGE_STORAGE),
            ),
            DataElement::new(
                tags::COMMAND_FIELD,
                VR::US,
                PrimitiveValue::from(C_STORE_RQ),
            ),
            DataElement::new(tags::MESSAGE_ID, VR::US, PrimitiveValue::from(7u16)),
            DataElement::new(
                tags::COMMAND_DATA_SET_TYPE,
                VR::US,
                PrimitiveValue::from(0u16),
            ),
            DataElement::new(
                tags::AFFECTED_SOP_INSTANCE_UID,
                VR::UI,
                PrimitiveValue::from("1.2.3"),
            ),
        ])
        .expect("encode");
        // The group length counts the bytes after it.
        assert_eq!(
            u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes")) as usize,
            bytes.len() - 12
        );
        let command = parse_command(&bytes).expect("parse");
        assert_eq!(command.field, C_STORE_RQ);
        assert_eq!(command.message_id, 7);
        assert!(command.has_data_set);
        assert_eq!(command.class, uids::CT_IMAGE_STORAGE);
        assert_eq!(command.instance, "1.2.3");
        assert!(parse_command(b"\x00\x00\x00\x00\x04\x00").is_err());
        // A length past the end, or undefined: refused before parsing.
        assert!(parse_command(b"\x00\x00\x00\x01\xff\xff\xff\xff").is_err());
        assert!(parse_command(b"\x08\x00\x18\x00\x00\x00\x00\x00").is_err());
        assert!(parse_command(&[]).is_err());
    }
}
