//! Bit-exact binary encodings of a [`ValueNet`] (description + weights) and of an [`Adam`]
//! state, for checkpoints and weight broadcasts. The full training checkpoint (method,
//! counters, run config) is assembled by the learner around these blobs.
//!
//! Network blob, all little-endian:
//! `b"FSRLNET\0"`, format version `u32`, kind `u8` (0 SARL, 1 LSTM-RL), sizes (SARL: four
//! lists `mlp1, mlp2, attention, mlp3`; LSTM-RL: `hidden u32` then the `mlp` list; a list is
//! `u32` count then `u32` values), parameter count `u64`, the parameters as `f32` bits in flat
//! layout order, then CRC-32 (IEEE) of every preceding byte.
//!
//! Adam blob: `b"FSRLADM\0"`, version `u32`, `lr, beta1, beta2, eps` as `f32` bits, step
//! count `u64`, length `u64`, `m`, `v` as `f32` bits, CRC-32.

use std::path::Path;

use crate::config::{LstmRlConfig, NetConfig, SarlConfig};
use crate::optim::{Adam, AdamConfig};
use crate::{PolicyError, ValueNet};

const NET_MAGIC: &[u8; 8] = b"FSRLNET\0";
const ADAM_MAGIC: &[u8; 8] = b"FSRLADM\0";
/// Version of both encodings.
pub const FORMAT_VERSION: u32 = 1;

/// Encodes a network (description and weights).
pub fn encode_net(net: &ValueNet) -> Vec<u8> {
    let mut out = Vec::with_capacity(64 + 4 * net.num_params());
    out.extend_from_slice(NET_MAGIC);
    put_u32(&mut out, FORMAT_VERSION);
    match net.config() {
        NetConfig::Sarl(c) => {
            out.push(0);
            for dims in [&c.mlp1_dims, &c.mlp2_dims, &c.attention_dims, &c.mlp3_dims] {
                put_dims(&mut out, dims);
            }
        }
        NetConfig::LstmRl(c) => {
            out.push(1);
            put_u32(&mut out, c.hidden_dim as u32);
            put_dims(&mut out, &c.mlp_dims);
        }
    }
    put_f32s(&mut out, net.params());
    finish(out)
}

/// Decodes [`encode_net`]'s output; any truncation, corruption or mismatch is an error.
pub fn decode_net(bytes: &[u8]) -> Result<ValueNet, PolicyError> {
    const WHAT: &str = "network weights";
    let mut r = Reader::new(bytes, NET_MAGIC, WHAT)?;
    let config = match r.u8()? {
        0 => NetConfig::Sarl(SarlConfig {
            mlp1_dims: r.dims()?,
            mlp2_dims: r.dims()?,
            attention_dims: r.dims()?,
            mlp3_dims: r.dims()?,
        }),
        1 => NetConfig::LstmRl(LstmRlConfig {
            hidden_dim: r.u32()? as usize,
            mlp_dims: r.dims()?,
        }),
        k => return Err(r.err(format!("unknown network kind {k}"))),
    };
    config.validate()?;
    let expected = config.num_params();
    let params = r.f32s(Some(expected))?;
    r.end()?;
    ValueNet::from_params(config, params)
}

/// Encodes an Adam state.
pub fn encode_adam(adam: &Adam) -> Vec<u8> {
    let mut out = Vec::with_capacity(64 + 8 * adam.m().len());
    out.extend_from_slice(ADAM_MAGIC);
    put_u32(&mut out, FORMAT_VERSION);
    let c = adam.config();
    for v in [c.lr, c.beta1, c.beta2, c.eps] {
        put_u32(&mut out, v.to_bits());
    }
    out.extend_from_slice(&adam.step_count().to_le_bytes());
    put_f32s(&mut out, adam.m());
    put_f32s(&mut out, adam.v());
    finish(out)
}

/// Decodes [`encode_adam`]'s output.
pub fn decode_adam(bytes: &[u8]) -> Result<Adam, PolicyError> {
    let mut r = Reader::new(bytes, ADAM_MAGIC, "Adam state")?;
    let mut f = || r.u32().map(f32::from_bits);
    let config = AdamConfig {
        lr: f()?,
        beta1: f()?,
        beta2: f()?,
        eps: f()?,
    };
    let step = r.u64()?;
    let m = r.f32s(None)?;
    let v = r.f32s(Some(m.len()))?;
    r.end()?;
    Adam::from_state(config, m, v, step)
}

/// Writes [`encode_net`] to `path` (via a temporary file and a rename).
pub fn save_net(net: &ValueNet, path: &Path) -> Result<(), PolicyError> {
    write_atomic(path, &encode_net(net))
}

/// Reads a network written by [`save_net`].
pub fn load_net(path: &Path) -> Result<ValueNet, PolicyError> {
    decode_net(&read(path)?)
}

/// Writes [`encode_adam`] to `path` (via a temporary file and a rename).
pub fn save_adam(adam: &Adam, path: &Path) -> Result<(), PolicyError> {
    write_atomic(path, &encode_adam(adam))
}

/// Reads an Adam state written by [`save_adam`].
pub fn load_adam(path: &Path) -> Result<Adam, PolicyError> {
    decode_adam(&read(path)?)
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> PolicyError + '_ {
    move |source| PolicyError::Io {
        path: path.to_owned(),
        source,
    }
}

fn read(path: &Path) -> Result<Vec<u8>, PolicyError> {
    std::fs::read(path).map_err(io_err(path))
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), PolicyError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = std::path::PathBuf::from(tmp);
    std::fs::write(&tmp, bytes).map_err(io_err(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io_err(path))
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_dims(out: &mut Vec<u8>, dims: &[usize]) {
    put_u32(out, dims.len() as u32);
    for &d in dims {
        put_u32(out, d as u32);
    }
}

fn put_f32s(out: &mut Vec<u8>, vals: &[f32]) {
    out.extend_from_slice(&(vals.len() as u64).to_le_bytes());
    for v in vals {
        out.extend_from_slice(&v.to_bits().to_le_bytes());
    }
}

fn finish(mut out: Vec<u8>) -> Vec<u8> {
    let crc = crc32fast::hash(&out);
    put_u32(&mut out, crc);
    out
}

/// Checks magic, version and checksum up front, then reads the body.
struct Reader<'a> {
    body: &'a [u8],
    pos: usize,
    what: &'static str,
}

impl<'a> Reader<'a> {
    fn new(bytes: &'a [u8], magic: &[u8; 8], what: &'static str) -> Result<Self, PolicyError> {
        let err = |reason: String| PolicyError::Decode { what, reason };
        if bytes.len() < magic.len() + 8 {
            return Err(err(format!("truncated: {} bytes", bytes.len())));
        }
        if &bytes[..8] != magic {
            return Err(err("wrong magic (not this kind of file)".to_owned()));
        }
        let (body, crc) = bytes.split_at(bytes.len() - 4);
        let stored = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
        let version = u32::from_le_bytes([body[8], body[9], body[10], body[11]]);
        if version != FORMAT_VERSION {
            return Err(err(format!(
                "format version {version}, this build reads {FORMAT_VERSION}"
            )));
        }
        if crc32fast::hash(body) != stored {
            return Err(err("checksum mismatch (truncated or corrupt)".to_owned()));
        }
        Ok(Self {
            body,
            pos: 12,
            what,
        })
    }

    fn err(&self, reason: String) -> PolicyError {
        PolicyError::Decode {
            what: self.what,
            reason,
        }
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], PolicyError> {
        if self.body.len() - self.pos < n {
            return Err(self.err(format!("truncated at byte {}", self.pos)));
        }
        let s = &self.body[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8, PolicyError> {
        Ok(self.take(1)?[0])
    }

    fn u32(&mut self) -> Result<u32, PolicyError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self) -> Result<u64, PolicyError> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }

    fn dims(&mut self) -> Result<Vec<usize>, PolicyError> {
        let n = self.u32()? as usize;
        if n > 64 {
            return Err(self.err(format!("{n} layers")));
        }
        (0..n).map(|_| self.u32().map(|d| d as usize)).collect()
    }

    fn f32s(&mut self, expected: Option<usize>) -> Result<Vec<f32>, PolicyError> {
        let n = self.u64()?;
        if let Some(e) = expected {
            if n != e as u64 {
                return Err(self.err(format!("{n} values, expected {e}")));
            }
        }
        let bytes = n
            .checked_mul(4)
            .and_then(|b| usize::try_from(b).ok())
            .ok_or_else(|| self.err(format!("{n} values")))?;
        let raw = self.take(bytes)?;
        Ok(raw
            .chunks_exact(4)
            .map(|c| f32::from_bits(u32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .collect())
    }

    fn end(&self) -> Result<(), PolicyError> {
        if self.pos != self.body.len() {
            return Err(self.err(format!("{} trailing bytes", self.body.len() - self.pos)));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::random_states;
    use crate::train::Trainer;
    use crate::StateBatch;

    #[test]
    fn export_import_round_trip_is_bit_exact() {
        for config in [NetConfig::sarl(), NetConfig::lstm_rl()] {
            let net = ValueNet::new(config, 99).unwrap();
            // Flat export → import.
            let flat = net.params().to_vec();
            let back = ValueNet::from_params(net.config().clone(), flat).unwrap();
            assert_eq!(bits(back.params()), bits(net.params()));
            // Encoded blob → decode.
            let decoded = decode_net(&encode_net(&net)).unwrap();
            assert_eq!(decoded.config(), net.config());
            assert_eq!(bits(decoded.params()), bits(net.params()));
            let data = random_states(5, 4, 0);
            let states = StateBatch::new(&data, 5, 4).unwrap();
            assert_eq!(bits(&decoded.values(states)), bits(&net.values(states)));
        }
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn files_and_adam_state_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let (b, n) = (6, 3);
        let data = random_states(b, n, 4);
        let states = StateBatch::new(&data, b, n).unwrap();
        let mut trainer = Trainer::new(
            ValueNet::new(NetConfig::sarl(), 1).unwrap(),
            AdamConfig::with_lr(1e-3),
        );
        for _ in 0..3 {
            trainer.fit(states, &[0.1; 6]).unwrap();
        }
        let (np, ap) = (dir.path().join("net.bin"), dir.path().join("adam.bin"));
        save_net(trainer.online(), &np).unwrap();
        save_adam(trainer.adam(), &ap).unwrap();
        let net = load_net(&np).unwrap();
        let adam = load_adam(&ap).unwrap();
        assert_eq!(&adam, trainer.adam());
        assert_eq!(bits(net.params()), bits(trainer.online().params()));
        // Resuming continues bit-for-bit.
        let mut resumed = Trainer::from_parts(net.clone(), net, adam).unwrap();
        let mut original = Trainer::from_parts(
            trainer.online().clone(),
            trainer.online().clone(),
            trainer.adam().clone(),
        )
        .unwrap();
        resumed.fit(states, &[0.2; 6]).unwrap();
        original.fit(states, &[0.2; 6]).unwrap();
        assert_eq!(
            bits(resumed.online().params()),
            bits(original.online().params())
        );
        assert!(load_net(&dir.path().join("missing.bin")).is_err());
    }

    #[test]
    fn damaged_blobs_are_clear_errors() {
        let net = ValueNet::new(NetConfig::lstm_rl(), 0).unwrap();
        let good = encode_net(&net);
        // Every truncation is an error, never a panic.
        for len in [0, 5, 12, 20, good.len() / 2, good.len() - 1] {
            assert!(decode_net(&good[..len]).is_err(), "truncated to {len}");
        }
        let mut flipped = good.clone();
        flipped[good.len() / 2] ^= 1;
        let msg = decode_net(&flipped).unwrap_err().to_string();
        assert!(msg.contains("checksum"), "{msg}");
        let mut wrong_magic = good.clone();
        wrong_magic[0] = b'X';
        assert!(decode_net(&wrong_magic)
            .unwrap_err()
            .to_string()
            .contains("magic"));
        assert!(decode_adam(&good).is_err());
        let adam = encode_adam(&Adam::new(AdamConfig::with_lr(0.1), 3));
        assert!(decode_net(&adam).is_err());
        assert!(decode_adam(&adam).is_ok());
    }
}
