//! Prints a summary of a loaded scene (meshes, materials, textures, cameras, lights):
//! `cargo run --release -p coordinator --example dump_scene -- SCENE.gltf`.

fn main() -> anyhow::Result<()> {
    let path = std::env::args().nth(1).expect("usage: dump_scene SCENE");
    let scene = common::gltf::load_path(std::path::Path::new(&path))?;
    for (i, m) in scene.meshes.iter().enumerate() {
        println!(
            "mesh {i} {}: {} vertices, {} triangles, normals {}, uv0 {}, uv1 {}, colors {}, material {}",
            m.name,
            m.positions.len(),
            m.indices.len(),
            m.normals.is_some(),
            m.uvs[0].is_some(),
            m.uvs[1].is_some(),
            m.colors.is_some(),
            m.material
        );
    }
    println!("{} instances", scene.instances.len());
    for (i, m) in scene.materials.iter().enumerate() {
        println!("material {i}: {m:?}");
    }
    for (i, t) in scene.textures.iter().enumerate() {
        println!(
            "texture {i}: {}x{} wrap {:?}/{:?} nearest {} mean {:?} first {:?}",
            t.width,
            t.height,
            t.wrap_s,
            t.wrap_t,
            t.nearest,
            worker::render::texture::mean(t, true),
            match &t.texels {
                common::scene::Texels::Rgba8(x) => format!("{:?}", &x[..x.len().min(4)]),
                common::scene::Texels::Rgba16(x) => format!("{:?} (16-bit)", &x[..x.len().min(4)]),
            }
        );
    }
    for c in &scene.cameras {
        println!("camera {}: {:?} at {:?}", c.name, c.projection, c.position());
    }
    for l in &scene.lights {
        println!("light {}: {:?} intensity {:?}", l.name, l.kind, l.intensity);
    }
    Ok(())
}
