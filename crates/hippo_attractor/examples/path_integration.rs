//! Drive the whole spatial memory along a winding 2-D trajectory and report how well each part tracks it.
//! `cargo run --release --example path_integration -- [seconds] [n_theta] [n_nu]`
use hippo_attractor::wrap_angle as wrap;
use hippo_attractor::{SpatialMemory, SpatialMemoryParams};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<f64> = std::env::args()
        .skip(1)
        .map(|s| s.parse().unwrap_or(0.0))
        .collect();
    let seconds = a.first().copied().unwrap_or(60.0);
    let mut p = SpatialMemoryParams::default();
    if let Some(&n) = a.get(1) {
        p.place.n_theta = n as usize;
        p.grid.iter_mut().for_each(|g| g.n_theta = n as usize);
    }
    if let Some(&m) = a.get(2) {
        p.grid.iter_mut().for_each(|g| g.n_nu = m as usize);
    }
    if let Ok(v) = std::env::var("PLACE") {
        let v = v
            .split(',')
            .map(str::parse)
            .collect::<Result<Vec<f64>, _>>()?;
        let [j0, j1, input_amp] = v[..] else {
            return Err("PLACE must be three numbers: j0,j1,input_amp".into());
        };
        (p.place.j0, p.place.j1, p.place.input_amp) = (j0, j1, input_amp);
    }
    if let Ok(v) = std::env::var("SUB") {
        p.max_substep_s = v.parse()?;
    }
    let mut sm = SpatialMemory::<f32>::new(p)?;
    let dt = 0.1;
    let (mut x, mut y, mut yaw) = (0.0f64, 0.0f64, 0.0f64);
    let mut dist = 0.0;
    let t0 = Instant::now();
    let frames = (seconds / dt) as usize;
    let mut worst_heading = 0.0f64;
    for f in 0..frames {
        let t = f as f64 * dt;
        let yaw_rate = 0.6 * (0.21 * t).sin() + 0.3 * (0.05 * t).cos();
        let speed = 15.0 + 14.0 * (0.13 * t).sin();
        let r = sm.step(yaw_rate, speed, dt, None)?;
        // Ground truth: same Euler integration per sub-step as the commanded constants over the frame.
        let n = r.substeps;
        for _ in 0..n {
            yaw += yaw_rate * dt / n as f64;
            x += speed * yaw.cos() * dt / n as f64;
            y += speed * yaw.sin() * dt / n as f64;
        }
        dist += speed * dt;
        worst_heading = worst_heading.max(wrap(r.hd.heading_rad - yaw).abs());
        if f % 100 == 99 || f + 1 == frames {
            let errs: Vec<String> = r
                .modules
                .iter()
                .map(|m| {
                    format!(
                        "k{} {:.2}%",
                        m.k,
                        100.0 * (m.position_m[0] - x).hypot(m.position_m[1] - y) / dist
                    )
                })
                .collect();
            println!(
                "t={:.0}s dist={dist:.0}m heading err {:.2}° (worst {:.2}°) ω̂ {:.3} vs {:.3} | {} | place {:.2}% σ {:?} fused σ {:?} bumps {:?}",
                t + dt,
                wrap(r.hd.heading_rad - yaw).abs().to_degrees(),
                worst_heading.to_degrees(),
                r.hd.yaw_rate_rad_s,
                yaw_rate,
                errs.join(", "),
                100.0 * (r.place_position_m[0] - x).hypot(r.place_position_m[1] - y) / dist,
                r.place.map(|b| b.std_rad),
                r.fused.map(|f| f.std_rad),
                r.modules.iter().map(|m| m.bumps.len()).collect::<Vec<_>>(),
            );
        }
    }
    println!(
        "{:.1} ms per frame",
        t0.elapsed().as_secs_f64() * 1e3 / frames as f64
    );
    Ok(())
}
