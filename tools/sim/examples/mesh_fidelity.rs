//! How far the physics shape (convex pieces) of each mesh object lies from its exact surface.
use parry3d::math::{Pose, Vector};
use psgrasp_sim::mesh::{load_mesh_set, MeshLibrary, MeshSet};
use rand::{Rng, SeedableRng};

fn main() {
    let dir =
        std::path::PathBuf::from(std::env::var("HOME").unwrap()).join(".cache/psgrasp/objects");
    for set in [MeshSet::Ycb, MeshSet::RandomUrdf] {
        let mut meshes = MeshLibrary::default();
        let lib = load_mesh_set(&dir, set, &mut meshes).unwrap();
        let mut rows = Vec::new();
        for obj in &lib.objects {
            let key = &obj.spec.name;
            let asset = meshes.get(key).unwrap().clone();
            let phys = meshes.convex_decomposition(key, 1.0).unwrap();
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
            let areas: Vec<f32> = asset
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| Vector::from(asset.vertices[i as usize]));
                    0.5 * (b - a).cross(c - a).length()
                })
                .collect();
            let total: f32 = areas.iter().sum();
            let (mut out2, mut out5, mut n) = (0, 0, 0);
            let mut worst = 0.0f32;
            for _ in 0..4000 {
                let mut r = rng.random::<f32>() * total;
                let mut k = 0;
                while k + 1 < areas.len() && r > areas[k] {
                    r -= areas[k];
                    k += 1;
                }
                let [a, b, c] =
                    asset.triangles[k].map(|i| Vector::from(asset.vertices[i as usize]));
                let (mut u, mut v) = (rng.random::<f32>(), rng.random::<f32>());
                if u + v > 1.0 {
                    u = 1.0 - u;
                    v = 1.0 - v;
                }
                let p = a + (b - a) * u + (c - a) * v;
                let proj = phys.project_point(&Pose::IDENTITY, p, true);
                let d = if proj.is_inside {
                    0.0
                } else {
                    (proj.point - p).length()
                };
                worst = worst.max(d);
                n += 1;
                if d > 0.002 {
                    out2 += 1;
                }
                if d > 0.005 {
                    out5 += 1;
                }
            }
            rows.push((
                key.clone(),
                format!("{:?}", obj.split),
                out2 as f32 / n as f32,
                out5 as f32 / n as f32,
                worst,
                asset.convex_parts.len(),
            ));
        }
        rows.sort_by(|a, b| b.2.total_cmp(&a.2));
        let mean2 = rows.iter().map(|r| r.2).sum::<f32>() / rows.len() as f32;
        let mean5 = rows.iter().map(|r| r.3).sum::<f32>() / rows.len() as f32;
        println!(
            "{set:?}: {} objects, mean share of surface >2 mm outside physics {:.3}, >5 mm {:.3}",
            rows.len(),
            mean2,
            mean5
        );
        for r in rows.iter().take(12) {
            println!(
                "  {:28} {:5} >2mm {:.3} >5mm {:.3} worst {:.1} mm pieces {}",
                r.0,
                r.1,
                r.2,
                r.3,
                r.4 * 1e3,
                r.5
            );
        }
    }
}
