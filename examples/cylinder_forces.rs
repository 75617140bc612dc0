//! Why the DFG 2D-1 lift on the staircase cylinder moves away from the
//! reference as the grid is refined (issue 42, item 1): the force on the body
//! by two independent methods, the body's rasterised geometry, and a control
//! whose lift is zero by symmetry.
//!
//! - **Surface**: the force on the staircase (`DfgChannel::force`, the
//!   library's `obstacle_force`), split into its pressure part (the same call
//!   with ν = 0) and its wall-shear part (the rest); and
//!   two variants: the pressure extrapolated to the faces from two fluid
//!   cells, and the shear as `ν ū_t / h` (the flux the Laplacian takes, which
//!   reads the solid's zero tangential faces a cell away).
//! - **Control volume**: the momentum balance over a rectangle around the body
//!   whose edges lie on cell faces,
//!
//!   ```text
//!   F = ∮ (−p n + ν ∇u·n − u (u·n)) dS − d/dt ∫ u dV
//!   ```
//!
//!   by the midpoint rule on each cell edge (pressure and tangential velocity
//!   averaged to the edge, normal derivatives by central differences), for
//!   several boxes; the time term from one more step. This is the library's
//!   `validation::control_volume_force` on a `validation::FaceBox`. It never looks at the
//!   staircase, so an error of the surface evaluation shows as a gap between
//!   the two, and an error of the flow field as both moving together.
//! - **What the step exchanges with the body**: one step from the steady
//!   state run piece by piece (boundaries, the old pressure gradient,
//!   advection, viscosity, projection; its velocity checked equal to the
//!   step's), each piece's change of the momentum inside a box set against
//!   the box's matching edge term: the rest is the momentum that piece takes
//!   out of the fluid at the body. The pieces sum to the control-volume
//!   force; set beside the surface evaluation's pressure and shear parts they
//!   show which part of the surface formula is not the flow's.
//! - **Geometry**: the solid cells' area, centroid and first moments about the
//!   true centre, and whether the mask is mirror-symmetric about y = 0.2.
//! - **Control** (`--cases symmetric`): the same body at the centre of a
//!   channel of height 0.40 (symmetric about y = 0.2), where the exact lift is 0.
//!
//! The DFG setup and the steady run are the library's 2D-1
//! (`diffphys::flow::validation::Dfg2d1`, as in `examples/cylinder.rs`): channel
//! 2.2 × 0.41, cylinder of diameter 0.1 at (0.2, 0.2), ν = 1e-3, parabolic
//! inflow of peak 0.3 (Ubar = 0.2, Re = 20), MacCormack with the limiter at
//! Courant 0.4 of Um (`--courant`), run from the inflow profile until no face
//! changes by more than `--tol` per unit time.
//! The last stdout line is the JSON of every figure, with the 2D-1 floor (drag
//! within 5 % of the published interval) at the finest grid of the `2d1` case;
//! the example exits non-zero after that line when the floor is missed.
//!
//! `--immersed` runs the same cases with the body as an immersed circle
//! (`diffphys::flow::immersed`, issue 42 item 2): the step's exchange then has
//! a fifth piece, the momentum the forcing takes out of the faces next to the
//! body. `--interior forced` makes no cell of the circle solid (every face
//! inside it forced to zero, the pressure across the body): the forcing is
//! then the whole exchange with the body; `--interior closed` also closes
//! those faces in the pressure operator (the body's force then adds the
//! pressure on them). The "two methods" line sets the
//! body's own force (`DfgChannel::body_force`: the forcing's momentum per
//! unit time, plus on a solid interior the staircase's exchange) beside the
//! control volume of half-width 0.10, their difference in % of the drag; on
//! an immersed body the floors add "within 1 % of the drag" (issue 42).
//! `--forcing consistent` forces the faces projection-consistently
//! (`ForcingScheme::ProjectionConsistent`: `F(u − τ∇Pⁿ) + τ∇Pⁿ`, so that the
//! projection leaves them on the interpolation). The slip line gives two
//! figures over Um, each the largest over the forced faces after one step
//! from the steady state: how far the projection moved them
//! (`|u_projected − u_forced|`) and how far they are from the interpolation of
//! the projected field (`|u_projected − F(u_projected)|`, the boundary
//! condition's residual).
//!
//! `cargo run --release --example cylinder_forces -- [--cpd 10,20,40]
//! [--cases 2d1,symmetric] [--tol 1e-4] [--max-time 40] [--courant 0.4]
//! [--immersed [--interior solid|forced|closed] [--forcing direct|consistent]]
//! [--small] [--out DIR]`
//! (`--small`: 10 cells across only)

mod common;
mod flow_common;

use std::time::Instant;

use diffphys::flow::advection::advect_velocity;
use diffphys::flow::boundaries::enforce_boundaries;
use diffphys::flow::diagnostics::{obstacle_force, ForceWeights};
use diffphys::flow::diffusion::diffuse;
use diffphys::flow::immersed::{consistent_forcing, immersed_forcing};
use diffphys::flow::pressure::{project, subtract_pressure_gradient};
use diffphys::flow::validation::{
    control_volume_force, Dfg2d1, DfgChannel, FaceBox, FloorCheck, CONTROL_VOLUME_CLEARANCE,
    DFG_2D1, DFG_2D1_HIGH_ACCURACY, DFG_CENTRE, DFG_DIAMETER, DFG_HEIGHT, DFG_NU,
};
use diffphys::flow::{FlowState, ForcingScheme, Interior, Obstacle, Scene, Splitting};
use ndarray::Array2;
use serde_json::{json, Value};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// Half-widths of the control volumes, squares centred on the cylinder.
const BOXES: [f64; 4] = [0.06, 0.08, 0.1, 0.15];

/// The rasterised body against the true disc: area, centroid offset, first
/// moments about the true centre, mirror symmetry about y = 0.2 and x = 0.2.
fn geometry(scene: &Scene) -> Value {
    let g = scene.grid();
    let solid = scene.solid();
    let (mut n, mut mx, mut my) = (0usize, 0.0, 0.0);
    let (mut asym_y, mut asym_x) = (0usize, 0usize);
    let mirror = |c: f64, h: f64, k: usize, len: usize| {
        // the cell whose centre is the mirror image of cell k's about c
        let m = 2.0 * c / h - 1.0 - k as f64;
        (m >= 0.0 && (m - m.round()).abs() < 1e-9 && (m.round() as usize) < len)
            .then(|| m.round() as usize)
    };
    for ((i, j), &s) in solid.indexed_iter() {
        if !s {
            continue;
        }
        n += 1;
        mx += (i as f64 + 0.5) * g.dx - DFG_CENTRE[0];
        my += (j as f64 + 0.5) * g.dy - DFG_CENTRE[1];
        if mirror(DFG_CENTRE[1], g.dy, j, g.ny).is_none_or(|m| !solid[[i, m]]) {
            asym_y += 1;
        }
        if mirror(DFG_CENTRE[0], g.dx, i, g.nx).is_none_or(|m| !solid[[m, j]]) {
            asym_x += 1;
        }
    }
    let cell = g.dx * g.dy;
    let area = n as f64 * cell;
    json!({
        "solid_cells": n, "area": area,
        "area_over_disc": area / (std::f64::consts::PI * DFG_DIAMETER * DFG_DIAMETER / 4.0),
        "centroid_offset": [mx * cell / area, my * cell / area],
        "first_moment": [mx * cell, my * cell],
        "cells_without_mirror_image_about_y0.2": asym_y,
        "cells_without_mirror_image_about_x0.2": asym_x,
    })
}

/// The pressure part of the surface force with the pressure extrapolated
/// linearly to each solid face from the two fluid cells along its normal
/// (the nearer one alone where the next is solid or outside): a variant of
/// the surface evaluation's pressure of the neighbouring cell.
fn pressure_extrapolated(scene: &Scene, s: &FlowState<f64>) -> [f64; 2] {
    let g = scene.grid();
    let solid = scene.solid();
    let (nx, ny) = (g.nx as isize, g.ny as isize);
    let fluid = |i: isize, j: isize| {
        i >= 0 && j >= 0 && i < nx && j < ny && !solid[[i as usize, j as usize]]
    };
    let p = |i: isize, j: isize| s.pressure[[i as usize, j as usize]];
    let mut f = [0.0; 2];
    for i in 0..nx {
        for j in 0..ny {
            if !fluid(i, j) {
                continue;
            }
            // n: the direction from the fluid cell into the solid one
            for (d, di, dj, area) in [
                (0, 1, 0, g.dy),
                (0, -1, 0, g.dy),
                (1, 0, 1, g.dx),
                (1, 0, -1, g.dx),
            ] {
                let (si, sj) = (i + di, j + dj);
                if !(si >= 0 && sj >= 0 && si < nx && sj < ny && solid[[si as usize, sj as usize]])
                {
                    continue;
                }
                let wall = if fluid(i - di, j - dj) {
                    1.5 * p(i, j) - 0.5 * p(i - di, j - dj)
                } else {
                    p(i, j)
                };
                f[d] += wall * (di + dj) as f64 * area;
            }
        }
    }
    f
}

/// The momentum one step of `scene` from the steady state `s` exchanges with
/// the body, piece by piece, over the box `b`: each piece of the step
/// (enforcing the boundaries, the old pressure gradient, advection,
/// viscosity, projection) is run as the step runs it, and what it adds to the
/// momentum inside `b` is set against what the control volume's matching edge
/// term brings in; the rest is what the piece takes out of the fluid at the
/// body: `body_k = edge_k − ΔM_k / dt`. The pressure pieces are set against
/// the pressure term, advection against the momentum flux, viscosity against
/// the viscous term, the immersed circle's forcing (if any) against nothing
/// (its faces lie inside the box); the pieces sum to the control-volume force.
/// Returns `[pressure, viscous, convective, boundaries, immersed forcing]`,
/// each `[F_x, F_y]`, and the slip of the forced faces over the inflow's peak
/// (0 without an immersed body): the largest `|u_projected − u_forced|` over
/// them (how far the projection moves them) and the largest
/// `|u_projected − F(u_projected)|` (how far they end from the interpolation
/// of the projected field: the boundary condition's residual).
fn step_budget(scene: &Scene, s: &FlowState<f64>, b: FaceBox) -> Result<([[f64; 2]; 5], [f64; 2])> {
    let params = scene.params::<f64>();
    let (g, faces, set, dt) = (scene.grid(), scene.faces(), scene.settings(), scene.dt());
    let (next, info) = scene.forward(s, &params)?;
    if info.substeps != 1 || set.splitting != Splitting::Incremental {
        return Err("the budget follows one incremental step without substeps".into());
    }
    let u0 = enforce_boundaries(g, faces, s.ux.view(), s.uy.view(), params.inflow.view())?;
    let q = subtract_pressure_gradient(
        g,
        faces,
        dt / 2.0,
        u0.0.view(),
        u0.1.view(),
        s.pressure.view(),
    )?;
    let a = advect_velocity(
        g,
        faces,
        set.advection,
        dt,
        (q.0.view(), q.1.view()),
        (u0.0.view(), u0.1.view()),
        params.wall_speed.view(),
    )?;
    let d = diffuse(
        scene.diffusion(),
        set.viscosity_mode,
        dt,
        a.0.view(),
        a.1.view(),
        params.viscosity,
        params.wall_speed.view(),
    )?;
    // the immersed circle's forcing, if any (the identity on the staircase)
    let f = match scene.immersed() {
        Some(body) => {
            let shape = ndarray::arr1(&body.circle().shape());
            match scene.immersed_scheme() {
                ForcingScheme::ProjectionConsistent => consistent_forcing(
                    body,
                    faces,
                    dt / 2.0,
                    (d.0.view(), d.1.view()),
                    s.pressure.view(),
                    shape.view(),
                )?,
                _ => immersed_forcing(body, d.0.view(), d.1.view(), shape.view())?,
            }
        }
        None => d.clone(),
    };
    let p = project(
        scene.pressure_system(),
        dt / 2.0,
        f.0.view(),
        f.1.view(),
        Some(s.pressure.view()),
    )?;
    if p.ux != next.ux || p.uy != next.uy {
        return Err("the pieces run one by one do not give the step's velocity".into());
    }
    let momentum = |ux: &Array2<f64>, uy: &Array2<f64>| {
        let state = FlowState {
            ux: ux.clone(),
            uy: uy.clone(),
            pressure: s.pressure.clone(),
            scalars: Vec::new(),
        };
        b.momentum(scene, &state)
    };
    let m = [
        momentum(&s.ux, &s.uy)?,
        momentum(&u0.0, &u0.1)?,
        momentum(&q.0, &q.1)?,
        momentum(&a.0, &a.1)?,
        momentum(&d.0, &d.1)?,
        momentum(&f.0, &f.1)?,
        momentum(&p.ux, &p.uy)?,
    ];
    let slip = match scene.immersed() {
        Some(body) => {
            let (mx, my) = body.forced_mask();
            let largest = |mask: &Array2<f64>, a: &Array2<f64>, b: &Array2<f64>| {
                mask.iter()
                    .zip(a.iter().zip(b))
                    .filter(|(m, _)| **m == 1.0)
                    .fold(0.0f64, |acc, (_, (x, y))| acc.max((x - y).abs()))
            };
            let shape = ndarray::arr1(&body.circle().shape());
            let target = immersed_forcing(body, p.ux.view(), p.uy.view(), shape.view())?;
            [
                largest(&mx, &p.ux, &f.0).max(largest(&my, &p.uy, &f.1)) / DFG_2D1.um,
                largest(&mx, &p.ux, &target.0).max(largest(&my, &p.uy, &target.1)) / DFG_2D1.um,
            ]
        }
        None => [0.0; 2],
    };
    let gain = |from: usize, to: usize| [0, 1].map(|k| (m[to][k] - m[from][k]) / dt);
    let cv = control_volume_force(scene, b, s, Some(&next), DFG_NU)?;
    let (old_p, new_p) = (gain(1, 2), gain(5, 6));
    Ok((
        [
            [0, 1].map(|k| cv.pressure[k] - old_p[k] - new_p[k]),
            [0, 1].map(|k| cv.viscous[k] - gain(3, 4)[k]),
            [0, 1].map(|k| cv.convective[k] - gain(2, 3)[k]),
            [0, 1].map(|k| -gain(0, 1)[k]),
            [0, 1].map(|k| -gain(4, 5)[k]),
        ],
        slip,
    ))
}

/// The viscous lift the step's Laplacian takes out of the fluid at the body
/// (`ForceWeights::momentum_exchange`'s y-component), split by the direction
/// of the link: `[tangential, normal]`, the links of each free y-face to an
/// obstacle y-face beside it (across a riser, along x) and to one above or
/// below it (the zero normal velocity of a tread, along y).
fn viscous_lift_by_link(scene: &Scene, s: &FlowState<f64>) -> [f64; 2] {
    let g = scene.grid();
    let solid = scene.solid();
    let (nx, ny) = (g.nx as isize, g.ny as isize);
    // y-face (i, b) lies between cells (i, b − 1) and (i, b)
    let body = |i: isize, b: isize| {
        (0..nx).contains(&i)
            && [b - 1, b]
                .into_iter()
                .any(|j| (0..ny).contains(&j) && solid[[i as usize, j as usize]])
    };
    let mut f = [0.0; 2];
    for i in 0..nx {
        for b in 1..ny {
            if body(i, b) {
                continue;
            }
            let v = s.uy[[i as usize, b as usize]];
            for (link, (di, db), weight) in [
                (0, (-1, 0), g.dy / g.dx),
                (0, (1, 0), g.dy / g.dx),
                (1, (0, -1), g.dx / g.dy),
                (1, (0, 1), g.dx / g.dy),
            ] {
                if body(i + di, b + db) {
                    f[link] += DFG_NU * weight * v;
                }
            }
        }
    }
    f
}

/// One steady 2D-1 run in a channel of `height` and its forces by both
/// methods; with the run's floors (those of `validation::Dfg2d1`).
fn run(cpd: usize, height: f64, opt: &Options) -> Result<(Value, Vec<FloorCheck>)> {
    let mut case = Dfg2d1::new(cpd)?;
    (case.channel.height, case.channel.courant) = (height, opt.courant);
    (case.tol, case.max_time) = (opt.tol, opt.max_time);
    case.channel.immersed = opt.immersed;
    case.channel.interior = match opt.interior.as_str() {
        "forced" => Interior::Forced,
        "closed" => Interior::Closed,
        _ => Interior::Solid,
    };
    case.channel.scheme = match opt.forcing.as_str() {
        "consistent" => ForcingScheme::ProjectionConsistent,
        _ => ForcingScheme::Direct,
    };
    let t0 = Instant::now();
    let result = case.run(&mut |_, _, _| Ok(()))?;
    let seconds = t0.elapsed().as_secs_f64();
    let (scene, s) = (&result.scene, &result.run.state);
    let (steps, rate, tol, dt) = (result.run.steps, result.run.rate, opt.tol, scene.dt());
    let coefficient = 2.0 / (DFG_2D1.ubar * DFG_2D1.ubar * DFG_DIAMETER);
    let lift_history: Vec<[f64; 2]> = result.history.iter().map(|h| [h[0], h[2]]).collect();
    let next = scene.forward(s, &scene.params())?.0;

    let total = DfgChannel::force(scene, s, DFG_NU)?;
    let pressure = DfgChannel::force(scene, s, 0.0)?;
    let c = |f: [f64; 2]| f.map(|v| coefficient * v);
    let shear = [total[0] - pressure[0], total[1] - pressure[1]];
    let extrapolated = pressure_extrapolated(scene, s);
    let variants = [
        [0, 1].map(|d| extrapolated[d] + shear[d]),
        [0, 1].map(|d| pressure[d] + 0.5 * shear[d]),
    ];
    let g = scene.grid();
    let weights = ForceWeights::momentum_exchange(g, scene.solid());
    let e = obstacle_force(
        &weights,
        s.ux.view(),
        s.uy.view(),
        s.pressure.view(),
        DFG_NU,
    )?;
    let exchange = c([e[0], e[1]]);
    println!(
        "cpd {cpd:3}, height {height}: {}x{} cells, {steps} steps to t = {:.2} ({}, rate {rate:.1e}; {seconds:.1} s)",
        g.nx,
        g.ny,
        steps as f64 * dt,
        if rate < tol { "steady" } else { "NOT steady" }
    );
    let st = c([0, 1].map(|d| pressure[d] + shear[d]));
    let links = viscous_lift_by_link(scene, s).map(|f| coefficient * f);
    // the staircase's formulas read solid cells; a forced interior has none
    let has_solid = scene.solid().iter().any(|&c| c);
    if has_solid {
        println!(
            "  surface        cD {:.4} cL {:+.5}   (pressure cD {:.4} cL {:+.5}; shear cD {:.4} cL {:+.5})",
            st[0],
            st[1],
            c(pressure)[0],
            c(pressure)[1],
            c(shear)[0],
            c(shear)[1]
        );
        println!(
            "  surface variants: pressure extrapolated to the face cD {:.4} cL {:+.5}; shear nu u_t/h cD {:.4} cL {:+.5}",
            c(variants[0])[0],
            c(variants[0])[1],
            c(variants[1])[0],
            c(variants[1])[1]
        );
        println!(
            "  surface, the step's exchange (ForceWeights::momentum_exchange): cD {:.4} cL {:+.5}   (viscous cL {:+.5}: tangential links {:+.5}, normal links {:+.5})",
            exchange[0],
            exchange[1],
            exchange[1] - c(pressure)[1],
            links[0],
            links[1]
        );
    } else {
        println!("  surface (the staircase's formulas): no solid cells");
    }
    let mut boxes = Vec::new();
    let mut forcing_exchange = [0.0; 2];
    let mut slip = [0.0; 2];
    // the circle's cells, solid or (a forced interior) fluid
    let body_cells = Obstacle::cylinder(DFG_CENTRE, DFG_DIAMETER / 2.0).rasterise(g)?;
    for a in BOXES {
        let b = FaceBox::around(g, DFG_CENTRE, a);
        let clearance = b.clearance(&body_cells);
        if clearance < CONTROL_VOLUME_CLEARANCE {
            continue;
        }
        let f = control_volume_force(scene, b, s, Some(&next), DFG_NU)?;
        let t = c(f.total());
        println!(
            "  CV |x-0.2|,|y-0.2| <= {a:.2} ({clearance:2} cells clear): cD {:.4} cL {:+.5}   (pressure cL {:+.5}, viscous {:+.5}, convective {:+.5}, unsteady {:+.1e})",
            t[0],
            t[1],
            c(f.pressure)[1],
            c(f.viscous)[1],
            c(f.convective)[1],
            c(f.unsteady)[1]
        );
        let (budget, step_slip) = step_budget(scene, s, b)?;
        let budget = budget.map(c);
        slip = step_slip;
        forcing_exchange = budget[4];
        println!(
            "      exchanged with the body by the step's pieces: pressure cD {:.4} cL {:+.5}, viscosity cD {:.4} cL {:+.5}, advection cD {:.4} cL {:+.5}, immersed forcing cD {:.4} cL {:+.5}, boundaries cL {:+.1e}",
            budget[0][0], budget[0][1], budget[1][0], budget[1][1], budget[2][0], budget[2][1], budget[4][0], budget[4][1], budget[3][1]
        );
        boxes.push(json!({
            "exchanged_with_body": {"pressure": budget[0], "viscosity": budget[1],
                                    "advection": budget[2], "boundaries": budget[3],
                                    "immersed_forcing": budget[4]},
            "half_width": a, "faces": [b.i0, b.i1, b.j0, b.j1], "clearance_cells": clearance,
            "cd": t[0], "cl": t[1],
            "parts_cd": {"pressure": c(f.pressure)[0], "viscous": c(f.viscous)[0],
                         "convective": c(f.convective)[0], "unsteady": c(f.unsteady)[0]},
            "parts_cl": {"pressure": c(f.pressure)[1], "viscous": c(f.viscous)[1],
                         "convective": c(f.convective)[1], "unsteady": c(f.unsteady)[1]},
        }));
    }
    let with_forcing = [0, 1].map(|k| exchange[k] + forcing_exchange[k]);
    let body = c(DfgChannel::body_force(scene, s)?);
    let cv = result.control_volume;
    let apart = [0, 1].map(|d| 100.0 * (body[d] - cv[d]) / cv[0]);
    if scene.immersed().is_some() {
        println!(
            "  surface, the step's exchange + the immersed forcing's: cD {:.4} cL {:+.5}",
            with_forcing[0], with_forcing[1]
        );
        println!(
            "  slip of the forced faces after the projection: max |u_projected - u_forced| / Um = {:.3e}, max |u_projected - F(u_projected)| / Um = {:.3e}",
            slip[0], slip[1]
        );
        println!(
            "  two methods: forcing exchange (DfgChannel::body_force) cD {:.4} cL {:+.5} | control volume {:.2} cD {:.4} cL {:+.5} | apart {:+.3} % / {:+.3} % of cD",
            body[0], body[1], case.channel.cv_half_width, cv[0], cv[1], apart[0], apart[1]
        );
    }
    let dp = result.values[2];
    println!("  dp {dp:.5} (reference {:.5})", DFG_2D1_HIGH_ACCURACY[2]);
    let geo = geometry(scene);
    if has_solid {
        println!(
            "  body: {} solid cells, area/disc {:.4}, centroid offset ({:+.1e}, {:+.1e}), cells without a mirror image about y = 0.2: {}",
            geo["solid_cells"],
            geo["area_over_disc"].as_f64().unwrap_or(f64::NAN),
            geo["centroid_offset"][0].as_f64().unwrap_or(f64::NAN),
            geo["centroid_offset"][1].as_f64().unwrap_or(f64::NAN),
            geo["cells_without_mirror_image_about_y0.2"]
        );
    } else {
        println!("  body: no solid cells (the circle's faces are forced)");
    }
    let row = json!({
        "cpd": cpd, "height": height, "immersed": opt.immersed, "nx": g.nx, "ny": g.ny, "h": g.dx, "dt": dt,
        "courant": opt.courant, "steps": steps, "time": steps as f64 * dt, "steady": rate < tol, "tol": tol,
        "rate_at_end": rate, "wall_s": seconds,
        "surface": {"cd": st[0], "cl": st[1],
                    "pressure": c(pressure), "shear": c(shear),
                    "pressure_extrapolated_to_face": c(variants[0]),
                    "shear_over_h": c(variants[1]),
                    "momentum_exchange": exchange,
                    "momentum_exchange_plus_immersed_forcing": with_forcing,
                    "momentum_exchange_viscous_cl_tangential_normal": links},
        "control_volume": boxes,
        "body_force": {"cd": body[0], "cl": body[1], "interior": opt.interior,
                       "control_volume_cd_cl": cv,
                       "apart_percent_of_cd": apart,
                       "forcing": opt.forcing,
                       "forced_face_slip_over_um": slip[0],
                       "forced_face_residual_over_um": slip[1]},
        "dp": dp,
        "geometry": geo,
        "surface_cl_history": lift_history,
    });
    Ok((row, result.floors))
}

/// Where the staircase cylinder's forces come from: surface integral and
/// control-volume momentum balance side by side.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    #[command(flatten)]
    opt: Options,
}

#[derive(clap::Args)]
struct Options {
    /// Grids, as cells across the cylinder's diameter, at least 4 each (10 with
    /// --small).
    #[arg(long, value_name = "LIST", value_delimiter = ',', default_values_t = [10, 20],
          default_value_if("small", "true", "10"))]
    cpd: Vec<usize>,
    /// Cases: DFG 2D-1, and the symmetric control (the body at the channel's centre).
    #[arg(long, value_name = "LIST", value_delimiter = ',', ignore_case = true,
          value_parser = ["2d1", "symmetric"],
          default_values_t = ["2d1".to_string(), "symmetric".to_string()])]
    cases: Vec<String>,
    /// Time units before a run stops unsteady.
    #[arg(long, value_name = "T", default_value_t = 40.0)]
    max_time: f64,
    /// Steady when the velocity changes by less than this per unit time.
    #[arg(long, default_value_t = 1e-4)]
    tol: f64,
    /// Courant number at the mean inflow speed.
    #[arg(long, default_value_t = 0.4)]
    courant: f64,
    /// The body as an immersed circle (direct forcing on the faces next to
    /// it) instead of the staircase.
    #[arg(long)]
    immersed: bool,
    /// What lies inside the immersed circle: solid cells (the staircase's,
    /// pinned), faces forced to zero with the pressure across the body
    /// (forced), or those faces also closed in the pressure operator (closed).
    #[arg(long, default_value = "solid", value_parser = ["solid", "forced", "closed"])]
    interior: String,
    /// How the immersed circle's faces are forced: the interpolation before
    /// the projection (direct), or projection-consistently (the predicted
    /// pressure gradient taken out before the interpolation and put back).
    #[arg(long, default_value = "direct", value_parser = ["direct", "consistent"])]
    forcing: String,
}

fn parse() -> Result<(common::ExampleArgs, Options)> {
    let Cli { common, mut opt } = common::parse_args("cylinder_forces")?;
    if opt.cpd.iter().any(|&c| c < 4) {
        return Err("--cpd: at least 4 cells across the diameter".into());
    }
    opt.cases.iter_mut().for_each(|c| *c = c.to_lowercase());
    Ok((common, opt))
}

fn main() -> Result<()> {
    let (args, opt) = parse()?;
    let mut out = serde_json::Map::new();
    out.insert("reference_cd_cl".into(), json!(DFG_2D1_HIGH_ACCURACY[..2]));
    let stated = *opt.cpd.iter().max().expect("at least one grid");
    let mut floors = Vec::new();
    for case in &opt.cases {
        let height = if case == "2d1" { DFG_HEIGHT } else { 0.40 };
        println!("{case}: channel 2.2 x {height}, cylinder at (0.2, 0.2)");
        let mut rows = Vec::new();
        for &c in &opt.cpd {
            let (row, run_floors) = run(c, height, &opt)?;
            rows.push(row);
            // the DFG intervals are of the 0.41 channel; the floor is checked
            // at the finest grid, as in examples/cylinder.rs
            if case == "2d1" && c == stated {
                floors = run_floors;
            }
        }
        out.insert(case.clone(), Value::Array(rows));
    }
    for f in &floors {
        println!("floor (2d1, cpd {stated}): {f}");
    }
    out.insert("floor".into(), flow_common::floors_json(&floors));
    out.insert(
        "floor_applies_to".into(),
        if floors.is_empty() {
            json!("none: the 2D-1 floor needs the 2d1 case")
        } else {
            json!({"case": "2d1", "cells_per_diameter": stated})
        },
    );
    let path = args.out.join("cylinder_forces.json");
    std::fs::write(
        &path,
        serde_json::to_string_pretty(&Value::Object(out.clone()))?,
    )?;
    println!("wrote {}", path.display());
    common::print_json_line(&Value::Object(out));
    flow_common::require_floors(&format!("cylinder_forces at cpd {stated}"), &floors)
}
