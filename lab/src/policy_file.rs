//! The policy a command is given: a model file, a checkpoint, or a run directory (its policy by
//! the run's `train.select`), loaded with a message naming it, labelled for a report, and
//! identified by the SHA-256 of its bytes.

use std::path::{Path, PathBuf};

use anyhow::Context;
use learner::model::{self, ArtifactKind, Model};

/// A policy file (model file or checkpoint) and the run directory it belongs to, if any.
pub struct Input {
    pub checkpoint: PathBuf,
    pub run_dir: Option<PathBuf>,
}

/// A short name: the run directory's name, else `<dir>/<file stem>` of the checkpoint.
pub fn label_of(input: &Input) -> String {
    let name = |p: &Path| {
        p.file_name().map_or_else(
            || p.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    match &input.run_dir {
        Some(d) => name(&d.canonicalize().unwrap_or_else(|_| d.clone())),
        None => {
            let stem = input
                .checkpoint
                .file_stem()
                .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
            match input.checkpoint.parent().map(name) {
                Some(dir) if !dir.is_empty() => format!("{dir}/{stem}"),
                _ => stem,
            }
        }
    }
}

/// Loads the policy of a model file or a checkpoint (told apart by content) with a message
/// naming it.
pub fn load_policy(path: &Path) -> anyhow::Result<(Model, ArtifactKind)> {
    model::load_policy(path).with_context(|| format!("cannot load {}", path.display()))
}

/// SHA-256 of a file's bytes, 64 lowercase hex digits (as `sha256sum`): the content id a report
/// records for the file it evaluated ([`crate::report::SubjectReport::checkpoint_sha256`]).
///
/// Not a CRC: model files and checkpoints end with the CRC-32 of their payload, and the CRC-32 of
/// such a file is the same for every payload of one length (CRC's residue), so it told the
/// weights of two runs of one configuration apart no better than their size did.
pub fn file_sha256(path: &Path) -> anyhow::Result<String> {
    use sha2::Digest;
    let mut f =
        std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut hasher = sha2::Sha256::new();
    std::io::copy(&mut f, &mut hasher)
        .with_context(|| format!("cannot read {}", path.display()))?;
    Ok(hex(&hasher.finalize()))
}

/// [`file_sha256`] of bytes already read.
pub fn bytes_sha256(bytes: &[u8]) -> String {
    use sha2::Digest;
    hex(&sha2::Sha256::digest(bytes))
}

fn hex(digest: &[u8]) -> String {
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// A model file names its method, trained setting and seed (its file name need not); a
/// checkpoint keeps its run's name.
pub fn subject_label(input: &Input, model: &Model, kind: ArtifactKind) -> String {
    match kind {
        ArtifactKind::Model => format!(
            "{} (trained {}, seed {})",
            model.method, model.setting, model.run_seed
        ),
        ArtifactKind::Checkpoint => label_of(input),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy_choice::resolve_input;

    #[test]
    fn inputs_are_labelled_and_hashed_and_bad_paths_named() {
        let tmp = tempfile::tempdir().unwrap();
        let file = tmp
            .path()
            .join("models")
            .join("fsrl-env1-invisible-s0.fsrlm");
        std::fs::create_dir_all(file.parent().unwrap()).unwrap();
        std::fs::write(&file, b"abc").unwrap();
        // sha256sum of "abc".
        assert_eq!(
            file_sha256(&file).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(bytes_sha256(b"abc"), file_sha256(&file).unwrap());
        let input = resolve_input(&file, None).unwrap();
        assert_eq!(input.run_dir, None);
        assert_eq!(label_of(&input), "models/fsrl-env1-invisible-s0");

        let e = format!(
            "{:#}",
            resolve_input(&tmp.path().join("nothing"), None)
                .err()
                .unwrap()
        );
        assert!(e.contains("no such checkpoint or run directory"), "{e}");
        let e = format!("{:#}", resolve_input(tmp.path(), None).err().unwrap());
        assert!(e.contains("not a run directory"), "{e}");
        let e = format!("{:#}", load_policy(&file).err().unwrap());
        assert!(
            e.contains("cannot load") && e.contains("fsrl-env1-invisible-s0"),
            "{e}"
        );
    }
}
