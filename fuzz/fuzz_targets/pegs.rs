#![no_main]

// Each target uses one of the shared readers.
#[allow(dead_code)]
#[path = "../readers.rs"]
mod readers;
#[path = "../scratch.rs"]
mod scratch;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    // Errors are the expected answer to bad bytes; only panics, hangs and
    // runaway allocations are findings.
    let _ = readers::pegs(scratch::dir(), data);
});
