//! The one way shaders/*.wgsl reach this crate. For every kernel of `KERNELS` it concatenates
//! the WGSL files the kernel is made of, validates the result with naga (a broken shader fails
//! the build, not a render) and reflects what the host must agree on:
//! - `$OUT_DIR/wgsl.rs`: the uniform structs as `#[repr(C)]` Rust structs, field by field, with
//!   compile-time checks that every field's Rust offset is naga's WGSL offset, and the scalar
//!   module constants (TILE, MAX_D, ...), so each is defined once, in WGSL;
//! - `$OUT_DIR/kernels.rs`: the `Kernel` enum with each kernel's source, entry point, workgroup
//!   size, bindings and pipeline-overridable constants.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use naga::valid::{Capabilities, ValidationFlags, Validator};

mod reflect;
use reflect::Reflected;

/// A compute kernel: the `Kernel` variant, the files concatenated (in order, without
/// `.wgsl`), the entry point and the pipeline-overridable constants it is built with.
struct Def {
    name: &'static str,
    files: &'static [&'static str],
    entry: &'static str,
    constants: &'static [(&'static str, f64)],
}

const fn def(name: &'static str, files: &'static [&'static str], entry: &'static str) -> Def {
    Def {
        name,
        files,
        entry,
        constants: &[],
    }
}

const PROJECT: &[&str] = &["splat_common", "splat_project", "project"];
const SORT: &[&str] = &["splat_common", "sort"];
const RASTER_FWD: &[&str] = &["splat_common", "rasterize_fwd"];

const KERNELS: &[Def] = &[
    def("ScanBlocks", &["scan"], "scan_blocks"),
    def("AddOffsets", &["scan"], "add_offsets"),
    def("Project", PROJECT, "main"),
    def("SortHistogram", SORT, "histogram"),
    def("SortScatter", SORT, "scatter"),
    def("CountTiles", &["splat_common", "count_tiles"], "main"),
    def("EmitKeys", &["splat_common", "emit_keys"], "main"),
    def("TileRanges", &["splat_common", "tile_ranges"], "main"),
    def("RasterizeFwd", RASTER_FWD, "main"),
    // The counting build: the same source with its work tallies switched on.
    Def {
        constants: &[("COUNT_WORK", 1.0)],
        ..def("RasterizeFwdCount", RASTER_FWD, "main")
    },
    // Two ways of adding float gradients (the file declaring `grads` and `grad_add`) times two
    // ways of summing them before the atomics (the file declaring `grad_sum`).
    def(
        "RasterizeBwd",
        &[
            "splat_common",
            "grads_float",
            "reduce_subgroup",
            "rasterize_bwd",
        ],
        "main",
    ),
    def(
        "RasterizeBwdCas",
        &[
            "splat_common",
            "grads_cas",
            "reduce_subgroup",
            "rasterize_bwd",
        ],
        "main",
    ),
    def(
        "RasterizeBwdSolo",
        &[
            "splat_common",
            "grads_float",
            "reduce_invocation",
            "rasterize_bwd",
        ],
        "main",
    ),
    def(
        "RasterizeBwdCasSolo",
        &[
            "splat_common",
            "grads_cas",
            "reduce_invocation",
            "rasterize_bwd",
        ],
        "main",
    ),
    def(
        "ProjectBwd",
        &["splat_common", "splat_project", "project_bwd"],
        "main",
    ),
];

/// Kernels that use the channel count `D`: the host declares it per pipeline (1..=MAX_D), so
/// their per-channel loops unroll; WGSL overrides cannot size the function-local arrays.
const PER_CHANNEL: &[&str] = &[
    "RasterizeFwd",
    "RasterizeFwdCount",
    "RasterizeBwd",
    "RasterizeBwdCas",
    "RasterizeBwdSolo",
    "RasterizeBwdCasSolo",
];

/// Files whose kernels need an optional device feature: naga validates them with the capability
/// and the generated `Kernel::features` names the wgpu feature the device must have enabled.
const FEATURES: &[(&str, Capabilities, &str)] = &[
    (
        "grads_float",
        Capabilities::SHADER_FLOAT32_ATOMIC,
        "SHADER_FLOAT32_ATOMIC",
    ),
    ("reduce_subgroup", Capabilities::SUBGROUP, "SUBGROUP"),
];

/// The (naga capabilities, wgpu feature names) a kernel's files need.
fn needs(k: &Def) -> (Capabilities, Vec<&'static str>) {
    let mut caps = Capabilities::default();
    let mut names = Vec::new();
    for (file, cap, name) in FEATURES {
        if k.files.contains(file) {
            caps |= *cap;
            names.push(*name);
        }
    }
    (caps, names)
}

/// How the host declares `D` before a per-channel kernel's text (also emitted into `source`).
macro_rules! d_decl {
    () => {
        "const D: u32 = {}u;\n"
    };
}

fn d_decl(d: u32) -> String {
    format!(d_decl!(), d)
}

fn fail(msg: String) -> ! {
    panic!("\n\nshader build (crates/raster/build/main.rs): {msg}\n")
}

fn main() {
    // Read at run time: env! would bake in the path this script was compiled at, and a target
    // directory shared by two checkouts (CI's and a developer's) would then read the other's shaders.
    let manifest = std::env::var("CARGO_MANIFEST_DIR")
        .unwrap_or_else(|e| fail(format!("CARGO_MANIFEST_DIR: {e}")));
    let dir = Path::new(&manifest).join("../../shaders");
    let dir = dir
        .canonicalize()
        .unwrap_or_else(|e| fail(format!("{}: {e}", dir.display())));
    println!("cargo:rerun-if-changed={}", dir.display());
    println!("cargo:rerun-if-changed=build");
    let mut files = BTreeMap::new();
    for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| fail(format!("{e}"))) {
        let path = entry.unwrap_or_else(|e| fail(format!("{e}"))).path();
        if path.extension().and_then(|e| e.to_str()) != Some("wgsl") {
            continue;
        }
        println!("cargo:rerun-if-changed={}", path.display());
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or_else(|| fail(format!("{}: not a UTF-8 name", path.display())))
            .to_string();
        let text = std::fs::read_to_string(&path)
            .unwrap_or_else(|e| fail(format!("{}: {e}", path.display())));
        files.insert(stem, (path, text));
    }
    for stem in files.keys() {
        if !KERNELS.iter().any(|k| k.files.contains(&stem.as_str())) {
            fail(format!(
                "shaders/{stem}.wgsl is part of no kernel: add it to KERNELS"
            ));
        }
    }

    let mut reflected = Reflected::default();
    let mut rows = Vec::new();
    for k in KERNELS {
        let parts: Vec<&(PathBuf, String)> = (k.files.iter())
            .map(|f| {
                files
                    .get(*f)
                    .unwrap_or_else(|| fail(format!("{}: shaders/{f}.wgsl not found", k.name)))
            })
            .collect();
        let text: String = parts.iter().map(|(_, t)| format!("{t}\n")).collect();
        let per_channel = PER_CHANNEL.contains(&k.name);
        let (module, info) = if per_channel {
            // Every channel count compiles; 1 and MAX_D are the extremes of the loops.
            let (module, _) = check(k, &format!("{}{text}", d_decl(1)));
            check(k, &format!("{}{text}", d_decl(max_d(&module, k))))
        } else {
            check(k, &text)
        };
        reflected.add(&module, k);
        rows.push(kernel_row(k, &module, &info, &parts, per_channel));
    }
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap_or_else(|e| fail(format!("{e}"))));
    write(&out.join("wgsl.rs"), &reflected.emit());
    write(&out.join("kernels.rs"), &emit_kernels(&rows));
}

fn write(path: &Path, text: &str) {
    std::fs::write(path, text).unwrap_or_else(|e| fail(format!("{}: {e}", path.display())));
}

/// Parse and validate one kernel's source; the build fails with naga's message.
fn check(k: &Def, src: &str) -> (naga::Module, naga::valid::ModuleInfo) {
    let module = naga::front::wgsl::parse_str(src)
        .unwrap_or_else(|e| fail(format!("{}: {}", k.name, e.emit_to_string(src))));
    // The device enables optional features only where the adapter has them, and only the kernels
    // made of the files in FEATURES use them.
    let info = Validator::new(ValidationFlags::all(), needs(k).0)
        .validate(&module)
        .unwrap_or_else(|e| fail(format!("{}: {}", k.name, e.emit_to_string(src))));
    if !module.entry_points.iter().any(|e| e.name == k.entry) {
        fail(format!("{}: no entry point {:?}", k.name, k.entry));
    }
    for (name, _) in k.constants {
        if !module
            .overrides
            .iter()
            .any(|(_, o)| o.name.as_deref() == Some(name))
        {
            fail(format!("{}: no override {name}", k.name));
        }
    }
    (module, info)
}

/// MAX_D, the most feature channels a pipeline may declare `D` with.
fn max_d(module: &naga::Module, k: &Def) -> u32 {
    let init = (module.constants.iter())
        .find(|(_, c)| c.name.as_deref() == Some("MAX_D"))
        .map(|(_, c)| &module.global_expressions[c.init]);
    match init {
        Some(naga::Expression::Literal(naga::Literal::U32(v))) => *v,
        _ => fail(format!(
            "{}: needs `const MAX_D: u32` (shaders/splat_common.wgsl)",
            k.name
        )),
    }
}

/// The `Kernel` variant and, in the order of `METHODS`, its value of each property.
fn kernel_row(
    k: &Def,
    module: &naga::Module,
    info: &naga::valid::ModuleInfo,
    parts: &[&(PathBuf, String)],
    per_channel: bool,
) -> (&'static str, [String; 7]) {
    let (index, ep) = (module.entry_points.iter().enumerate())
        .find(|(_, e)| e.name == k.entry)
        .unwrap_or_else(|| fail(format!("{}: no entry point {:?}", k.name, k.entry)));
    let uses = info.get_entry_point(index);
    let mut bindings: Vec<(u32, String)> = (module.global_variables.iter())
        .filter(|(h, _)| !uses[*h].is_empty())
        .filter_map(|(_, g)| {
            let b = g.binding.as_ref()?;
            if b.group != 0 {
                fail(format!("{}: only bind group 0 is used", k.name));
            }
            Some((b.binding, g.name.clone().unwrap_or_default()))
        })
        .collect();
    bindings.sort();
    // The files themselves, so the source compiled in is the one validated here.
    let includes: Vec<String> = (parts.iter())
        .map(|(p, _)| format!("include_str!({:?}), \"\\n\"", p.display().to_string()))
        .collect();
    (
        k.name,
        [
            format!("concat!({})", includes.join(", ")),
            format!("{:?}", k.entry),
            format!("{:?}", ep.workgroup_size),
            format!("&{bindings:?}"),
            format!("&{:?}", k.constants),
            format!("{per_channel}"),
            format!(
                "&[{}]",
                (needs(k).1.iter())
                    .map(|f| format!("wgpu::Features::{f}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ],
    )
}

/// (doc, name, return type) of the `Kernel` methods that `kernel_row` fills.
const METHODS: [(&str, &str, &str); 7] = [
    (
        "The WGSL files, concatenated (`D` excluded: see `per_channel`).",
        "text",
        "&'static str",
    ),
    ("The entry point.", "entry", "&'static str"),
    (
        "`@workgroup_size` of the entry point.",
        "workgroup_size",
        "[u32; 3]",
    ),
    (
        "(binding, variable name) of every group-0 binding the entry point uses.",
        "bindings",
        "&'static [(u32, &'static str)]",
    ),
    (
        "Pipeline-overridable constants set when the pipeline is built.",
        "constants",
        "&'static [(&'static str, f64)]",
    ),
    (
        "Whether the source needs `const D` (feature channels) declared per pipeline.",
        "per_channel",
        "bool",
    ),
    (
        "Optional device features the kernel uses (`GpuContext::has` tells whether it may run).",
        "features",
        "&'static [wgpu::Features]",
    ),
];

fn emit_kernels(rows: &[(&str, [String; 7])]) -> String {
    let mut s =
        String::from("// Generated by crates/raster/build/main.rs from shaders/*.wgsl.\n\n");
    s.push_str(
        "/// Every compute kernel of the crate (the `KERNELS` of crates/raster/build/main.rs).\n",
    );
    s.push_str("#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]\npub enum Kernel {\n");
    for (name, _) in rows {
        let _ = writeln!(s, "    {name},");
    }
    s.push_str("}\n\nimpl Kernel {\n");
    let names: Vec<String> = rows.iter().map(|(n, _)| format!("Kernel::{n}")).collect();
    let _ = writeln!(
        s,
        "    pub const ALL: [Kernel; {}] = [{}];\n",
        rows.len(),
        names.join(", ")
    );
    for (col, (doc, method, ty)) in METHODS.iter().enumerate() {
        let _ = write!(
            s,
            "    /// {doc}\n    pub const fn {method}(self) -> {ty} {{\n        match self {{\n"
        );
        for (name, values) in rows {
            let _ = writeln!(s, "            Kernel::{name} => {},", values[col]);
        }
        s.push_str("        }\n    }\n\n");
    }
    let _ = write!(
        s,
        "    /// The kernel's full source: `D` declared as `d` first where it is per-channel.
    pub fn source(self, d: u32) -> std::borrow::Cow<'static, str> {{
        if self.per_channel() {{
            format!(concat!({:?}, \"{{}}\"), d, self.text()).into()
        }} else {{
            self.text().into()
        }}
    }}
}}
",
        d_decl!()
    );
    s
}
