//! Fuzz targets for spsr. Each target in `fuzz_targets/` is one function of [`harness`]
//! wrapped by [`fuzz_target!`]: with the `libfuzzer` feature a libFuzzer entry point, without
//! it a plain program that runs every file (and every file in every folder) named on its
//! command line, so that CI can build the targets and replay inputs with a stable toolchain
//! and no C++ compiler.

pub mod harness;

/// Defines the entry point of a fuzz target calling `$f(&[u8])`.
#[macro_export]
macro_rules! fuzz_target {
    ($f:path) => {
        #[cfg(feature = "libfuzzer")]
        libfuzzer_sys::fuzz_target!(|data: &[u8]| {
            $f(data);
        });

        #[cfg(not(feature = "libfuzzer"))]
        fn main() {
            std::process::exit($crate::replay(&$f));
        }
    };
}

/// Runs `f` on the content of every file named on the command line (folders: every file in
/// them, sorted). Returns the process exit code: 0, or 2 for a missing argument or an
/// unreadable file. A panic in `f` aborts the program, as in the fuzzer.
pub fn replay(f: &dyn Fn(&[u8])) -> i32 {
    let args: Vec<std::path::PathBuf> = std::env::args_os().skip(1).map(Into::into).collect();
    if args.is_empty() {
        eprintln!("usage: TARGET FILE_OR_FOLDER...  (runs the target on each file)");
        return 2;
    }
    let mut files = Vec::new();
    for a in &args {
        if a.is_dir() {
            let Ok(entries) = std::fs::read_dir(a) else {
                eprintln!("cannot read folder {}", a.display());
                return 2;
            };
            let mut v: Vec<_> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
            v.sort();
            files.extend(v.into_iter().filter(|p| p.is_file()));
        } else {
            files.push(a.clone());
        }
    }
    for p in &files {
        match std::fs::read(p) {
            Ok(data) => f(&data),
            Err(e) => {
                eprintln!("cannot read {}: {e}", p.display());
                return 2;
            }
        }
    }
    eprintln!("ran {} inputs", files.len());
    0
}
