//! The shared library's SONAME on Linux: `liblivegesture_c.so`. Without one, a program linked against the
//! library by its path (CMake's imported target `livegesture::livegesture` of the C SDK, scripts/release.sh)
//! records that absolute path as its dependency, and breaks when the SDK folder moves; with it the program
//! needs `liblivegesture_c.so`, found through its rpath or the loader's search path
//! (scripts/prove_release.sh checks the examples' dependencies).

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("linux") {
        println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,liblivegesture_c.so");
    }
}
