//! Times Brush's rasterizer (brush-render, burn + cubecl on wgpu) on a scene written by
//! `scripts/brush/side_by_side.py`, and writes its image and gradients for comparison.
//!
//! Usage: `evsplat-brush-bench SCENE_DIR REPEATS`. SCENE_DIR holds `scene.json` (n, size,
//! focal) and `scene.f32` (little-endian float32: means 3n, quats 4n (w, x, y, z), scales 3n
//! (standard deviations), opacities n (in [0, 1]), colours 3n, then the loss weights on the
//! image, size*size*3, and on the alpha, size*size). Writes `brush_image.f32` (size*size*4,
//! RGBA), `brush_grads.f32` (transforms 10n, SH coefficients 3n, raw opacities n) and prints
//! one JSON line of timings (seconds) and counts on stdout.
//!
//! Each timed call starts from host vectors and ends with host vectors, as evsplat's
//! `rasterize` does from and to CPU tensors: upload, render, read back (the image for the
//! forward; the gradients for forward+backward).

#![recursion_limit = "256"]

use std::path::PathBuf;
use std::time::Instant;

use brush_render::bwd::render_splats as render_splats_diff;
use brush_render::camera::Camera;
use brush_render::gaussian_splats::{SplatRenderMode, Splats};
use brush_render::kernels::camera_model::CameraModel::Pinhole;
use brush_render::sh::channel_to_sh;
use brush_render::{TextureMode, render_splats};
use burn::tensor::{Device, Tensor, TensorData, s};
use burn_wgpu::graphics::AutoGraphicsApi;
use burn_wgpu::{RuntimeOptions, WgpuDevice};
use glam::{Quat, Vec3};

struct Scene {
    n: usize,
    size: u32,
    focal: f64,
    means: Vec<f32>,
    quats: Vec<f32>,
    log_scales: Vec<f32>,
    raw_opac: Vec<f32>,
    sh: Vec<f32>,
    w_img: Vec<f32>,
    w_alpha: Vec<f32>,
}

fn json_number(text: &str, key: &str) -> f64 {
    let at = text
        .find(&format!("\"{key}\""))
        .unwrap_or_else(|| panic!("scene.json has no {key}"));
    let rest = &text[at + key.len() + 2..];
    let rest = rest[rest.find(':').expect("a ':' after the key") + 1..].trim_start();
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || "+-.eE".contains(c)))
        .unwrap_or(rest.len());
    rest[..end].parse().expect("a number")
}

fn load(dir: &PathBuf) -> Scene {
    let meta = std::fs::read_to_string(dir.join("scene.json")).expect("scene.json");
    let n = json_number(&meta, "n") as usize;
    let size = json_number(&meta, "size") as u32;
    let focal = json_number(&meta, "focal");
    let bytes = std::fs::read(dir.join("scene.f32")).expect("scene.f32");
    let all: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let px = (size * size) as usize;
    let lens = [3 * n, 4 * n, 3 * n, n, 3 * n, 3 * px, px];
    assert_eq!(all.len(), lens.iter().sum::<usize>(), "scene.f32 size");
    let mut parts = Vec::new();
    let mut at = 0;
    for len in lens {
        parts.push(all[at..at + len].to_vec());
        at += len;
    }
    let [means, quats, scales, opac, colours, w_img, w_alpha]: [Vec<f32>; 7] =
        parts.try_into().expect("seven parts");
    Scene {
        n,
        size,
        focal,
        means,
        quats,
        // Brush's parameters: log scales, opacity logits, degree-0 SH coefficients.
        log_scales: scales.iter().map(|s| s.ln()).collect(),
        raw_opac: opac.iter().map(|o| (o / (1.0 - o)).ln()).collect(),
        sh: colours.iter().map(|&c| channel_to_sh(c)).collect(),
        w_img,
        w_alpha,
    }
}

fn splats(scene: &Scene, device: &Device) -> Splats {
    Splats::from_raw(
        scene.means.clone(),
        scene.quats.clone(),
        scene.log_scales.clone(),
        scene.sh.clone(),
        scene.raw_opac.clone(),
        SplatRenderMode::Default,
        device,
    )
}

/// Camera at the origin looking along +z (OpenCV axes, as evsplat's identity view), with
/// focal length `focal` pixels and the principal point at the image centre.
fn camera(scene: &Scene) -> Camera {
    let half = (scene.size as f64 / 2.0 / scene.focal).atan();
    Camera::new(
        Vec3::ZERO,
        Quat::IDENTITY,
        2.0 * half,
        2.0 * half,
        glam::vec2(0.5, 0.5),
        Pinhole,
    )
}

async fn host(t: Tensor<1>) -> Vec<f32> {
    t.into_data_async()
        .await
        .expect("readback")
        .into_vec::<f32>()
        .expect("f32")
}

/// Forward: upload, render (f32 RGBA, `TextureMode::Float`, or Brush's packed u8 viewer
/// path), read the image back. Returns the image (f32 mode), (visible, tile pairs) and the
/// sum of the image's bytes (a checksum of what came back, either mode).
async fn forward(scene: &Scene, device: &Device, mode: TextureMode) -> (Vec<f32>, u32, u32, u64) {
    let s = splats(scene, device);
    let size = glam::uvec2(scene.size, scene.size);
    let (img, aux) = render_splats(s, &camera(scene), size, Vec3::ZERO, None, mode).await;
    let n = img.shape().num_elements();
    let data = img.reshape([n]).into_data_async().await.expect("readback");
    let checksum = data.as_bytes().iter().map(|&b| u64::from(b)).sum();
    let image = match mode {
        TextureMode::Float => data.into_vec::<f32>().expect("f32"),
        TextureMode::Packed => Vec::new(),
    };
    (image, aux.num_visible, aux.num_intersections, checksum)
}

/// Forward + backward: upload, render with the backward bookkeeping, loss = sum(w_img * rgb)
/// + sum(w_alpha * alpha), backward, read the three parameter gradients back.
async fn forward_backward(scene: &Scene, ad: &Device) -> Vec<f32> {
    let s = splats(scene, ad);
    let size = glam::uvec2(scene.size, scene.size);
    let out = render_splats_diff(s.clone(), &camera(scene), size, Vec3::ZERO).await;
    let sz = scene.size as usize;
    let w_img = Tensor::<3>::from_data(TensorData::new(scene.w_img.clone(), [sz, sz, 3]), ad);
    let w_alpha = Tensor::<3>::from_data(TensorData::new(scene.w_alpha.clone(), [sz, sz, 1]), ad);
    let rgb = out.img.clone().slice(s![.., .., 0..3]);
    let alpha = out.img.slice(s![.., .., 3..4]);
    let loss = (rgb * w_img).sum() + (alpha * w_alpha).sum();
    let grads = loss.backward();
    let n = scene.n;
    let g_t = s.transforms.grad(&grads).expect("transforms grad");
    let g_sh = s.sh_coeffs.grad(&grads).expect("sh grad");
    let g_o = s.raw_opacities.grad(&grads).expect("opacity grad");
    let mut all = host(g_t.reshape([10 * n])).await;
    all.extend(host(g_sh.reshape([3 * n])).await);
    all.extend(host(g_o).await);
    debug_assert_eq!(all.len(), 14 * n);
    all
}

fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

fn fmt_list(v: &[f64]) -> String {
    let items: Vec<String> = v.iter().map(|x| format!("{x:.6}")).collect();
    format!("[{}]", items.join(", "))
}

fn write_f32(path: PathBuf, v: &[f32]) {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(path, bytes).expect("write output");
}

#[tokio::main(flavor = "current_thread")]
async fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = PathBuf::from(args.get(1).expect("SCENE_DIR"));
    let repeats: usize = args.get(2).map_or(3, |r| r.parse().expect("REPEATS"));
    let scene = load(&dir);

    // As Brush's own processes set up burn (brush-process's burn_init_setup).
    let options = RuntimeOptions {
        tasks_max: 64,
        memory_config: burn_wgpu::MemoryConfiguration::ExclusivePages,
    };
    let setup =
        burn_wgpu::init_setup_async::<AutoGraphicsApi>(&WgpuDevice::DefaultDevice, options).await;
    let info = setup.adapter.get_info();
    let adapter = format!("{} ({:?}, {:?})", info.name, info.device_type, info.backend);
    let inner = Device::from(WgpuDevice::DefaultDevice);
    let ad = inner.clone().autodiff();

    let mut results: Vec<(String, Vec<f64>, Vec<f64>)> = Vec::new();
    // Per timed forward call: visible, tile pairs (as the render read them back), checksum.
    let mut counts: Vec<String> = Vec::new();
    // Warm-up (kernel compilation, pipelines, buffers), then the timed calls.
    let (image, visible, pairs, _) = forward(&scene, &inner, TextureMode::Float).await;
    forward(&scene, &inner, TextureMode::Packed).await;
    let grads = forward_backward(&scene, &ad).await;
    for name in ["fwd", "fwd packed", "fwd+bwd"] {
        let (mut wall, mut cpu) = (Vec::new(), Vec::new());
        for _ in 0..repeats {
            let (t0, c0) = (Instant::now(), cpu_seconds());
            match name {
                "fwd" | "fwd packed" => {
                    let mode = if name == "fwd" {
                        TextureMode::Float
                    } else {
                        TextureMode::Packed
                    };
                    let (_, v, p, sum) = forward(&scene, &inner, mode).await;
                    counts.push(format!("[\"{name}\", {v}, {p}, {sum}]"));
                }
                _ => drop(forward_backward(&scene, &ad).await),
            }
            wall.push(t0.elapsed().as_secs_f64());
            cpu.push(cpu_seconds() - c0);
        }
        results.push((name.to_owned(), wall, cpu));
    }
    write_f32(dir.join("brush_image.f32"), &image);
    write_f32(dir.join("brush_grads.f32"), &grads);

    let mut fields = vec![
        format!("\"adapter\": \"{adapter}\""),
        format!("\"visible\": {visible}"),
        format!("\"tile_pairs\": {pairs}"),
        format!("\"counts\": [{}]", counts.join(", ")),
    ];
    for (name, mut wall, mut cpu) in results {
        fields.push(format!("\"{name}\": {}", fmt_list(&wall)));
        fields.push(format!("\"{name} cpu\": {}", fmt_list(&cpu)));
        fields.push(format!("\"{name} median\": {:.6}", median(&mut wall)));
        fields.push(format!("\"{name} cpu median\": {:.6}", median(&mut cpu)));
    }
    println!("{{{}}}", fields.join(", "));
}
