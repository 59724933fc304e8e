//! One folder per fuzzing process, reused for every input; in RAM when the
//! machine has /dev/shm, so file writes do not slow the fuzzer down.

use std::path::Path;
use std::sync::OnceLock;

pub fn dir() -> &'static Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let shm = Path::new("/dev/shm");
        let builder = tempfile::Builder::new()
            .prefix("grainforce-fuzz-")
            .tempdir_in(shm);
        builder
            .or_else(|_| tempfile::tempdir())
            .expect("scratch folder")
    })
    .path()
}
