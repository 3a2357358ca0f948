//! The README's first command (render the shipped scene) works as written from the repository
//! root: a regression test for the commands users copy first.

use std::path::Path;
use std::process::Command;

#[test]
fn readme_render_command_works_as_written() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let block = readme.split("```sh").nth(1).expect("a ```sh block in the README");
    let command = block
        .lines()
        .find(|l| l.trim_start().starts_with("cargo run"))
        .expect("a `cargo run` line in the first ```sh block");
    let mut words = command.split_whitespace();
    assert_eq!(words.next(), Some("cargo"));
    let args: Vec<&str> = words.collect();
    let out_index = args.iter().position(|a| *a == "-o").expect("an -o OUT argument") + 1;
    let out = root.join(args[out_index]);
    let _ = std::fs::remove_file(&out);
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let output = Command::new(cargo).args(&args).current_dir(&root).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "`{command}` failed:\n{stderr}");
    assert!(out.exists(), "`{command}` wrote no {}", out.display());
    assert!(out.with_extension("png").exists());
    let _ = std::fs::remove_file(&out);
    let _ = std::fs::remove_file(out.with_extension("png"));
}
