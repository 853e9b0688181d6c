//! The envelope every message travels in: a [`Header`] and a typed [`Body`].

use std::fmt;
use std::mem::MaybeUninit;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::error::ValidationError;
use crate::ids::{RunId, SenderId};
pub use crate::kind::MessageKind;
use crate::PROTOCOL_VERSION;

/// Carried by every message. `protocol_version` is always the first field, so a receiver can
/// tell a message from another protocol version from garbage.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u16,
    /// What the body is.
    pub kind: MessageKind,
    /// The run this message belongs to.
    pub run: RunId,
    /// Who sent it.
    pub sender: SenderId,
    /// Per (sender, topic) sequence number, starting at 0, +1 per message published.
    pub seq: u64,
    /// Version of the policy weights that produced the content (0 before any weights, e.g.
    /// imitation episodes of the ORCA demonstrator). For [`crate::Weights`] it equals the
    /// weights' own version.
    pub policy_version: u64,
}

impl Header {
    /// A header for a message of kind `B::KIND` with the current protocol version.
    pub fn new<B: Body>(run: RunId, sender: SenderId, seq: u64, policy_version: u64) -> Self {
        Self {
            protocol_version: PROTOCOL_VERSION,
            kind: B::KIND,
            run,
            sender,
            seq,
            policy_version,
        }
    }
}

/// The body of a message: one type per [`MessageKind`].
pub trait Body: Serialize + DeserializeOwned + Clone + fmt::Debug + Send + Sync + 'static {
    /// The kind announced in the header.
    const KIND: MessageKind;
    /// Checks every invariant (dimensions, finiteness, limits, checksums). Called by
    /// [`crate::encode`] and [`crate::decode`].
    fn validate(&self) -> Result<(), ValidationError>;

    /// Encodes `header` + `body` without serde into `buf` (cleared, valid message) and returns
    /// `true`, where a hand-written codec exists (module `direct`); it writes exactly the bytes
    /// of the serde encoding. `false`: serde encodes.
    #[doc(hidden)]
    fn encode_direct(_header: &Header, _body: &Self, _buf: &mut Vec<u8>) -> bool {
        false
    }

    /// The exact length [`Body::encode_direct`] would write, where a hand-written codec exists.
    #[doc(hidden)]
    fn direct_len(_header: &Header, _body: &Self) -> Option<usize> {
        None
    }

    /// Writes what [`Body::encode_direct`] would into `out` from its start; `true` only if
    /// that filled `out` exactly (every byte initialised, nothing left over or cut off).
    #[doc(hidden)]
    fn direct_write(_header: &Header, _body: &Self, _out: &mut [MaybeUninit<u8>]) -> bool {
        false
    }

    /// Decodes a message laid out exactly as [`Body::encode_direct`] writes it (structure only;
    /// the codec checks version, kind and validity afterwards). `None`: serde decodes.
    #[doc(hidden)]
    fn decode_direct(_bytes: &[u8]) -> Option<Message<Self>> {
        None
    }
}

/// A header and a body: what is encoded, published and received.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Message<B> {
    /// Envelope.
    pub header: Header,
    /// Payload.
    pub body: B,
}

impl<B: Body> Message<B> {
    /// A message with a fresh header (see [`Header::new`]).
    pub fn new(run: RunId, sender: SenderId, seq: u64, policy_version: u64, body: B) -> Self {
        Self {
            header: Header::new::<B>(run, sender, seq, policy_version),
            body,
        }
    }
}

/// Borrowed view with the same serialised layout as [`Message`], so encoding never clones a body.
#[derive(Serialize)]
pub(crate) struct MessageRef<'a, B> {
    pub(crate) header: &'a Header,
    pub(crate) body: &'a B,
}
