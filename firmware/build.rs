//! Linker arguments for the board binary only (embassy example style).
fn main() {
    if std::env::var_os("CARGO_FEATURE_STM32").is_some() {
        println!("cargo:rustc-link-arg-bins=--nmagic");
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
