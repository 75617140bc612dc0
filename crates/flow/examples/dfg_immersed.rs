//! DFG 2D-1 or 2D-2 with the body as an immersed circle on a forced interior,
//! by either forcing scheme: the figures of docs/10's tables for the
//! consistent forcing (issue 42).
//!
//! ```sh
//! cargo run --release -p diffphys-flow --example dfg_immersed -- 2d1 20 consistent
//! cargo run --release -p diffphys-flow --example dfg_immersed -- 2d2 10 direct
//! ```
//!
//! 2D-1 prints cD, cL (the forcing's exchange and the control volume), dp and
//! the boundary condition's residual `max |u − F(u)|` over the forced faces
//! of the steady state, over Um; 2D-2 prints St and the largest cD and cL by
//! both methods.

use diffphys_flow::immersed::immersed_forcing;
use diffphys_flow::validation::{Dfg2d1, Dfg2d2, DfgChannel, DFG_2D1};
use diffphys_flow::{ForcingScheme, Interior};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

fn channel(mut c: DfgChannel, scheme: ForcingScheme) -> DfgChannel {
    c.immersed = true;
    c.interior = Interior::Forced;
    c.scheme = scheme;
    c
}

fn steady(cpd: usize, scheme: ForcingScheme) -> Result<()> {
    let mut case = Dfg2d1::new(cpd)?;
    case.channel = channel(case.channel, scheme);
    let r = case.run(&mut |_, _, _| Ok(()))?;
    let (scene, s) = (&r.scene, &r.run.state);
    let body = scene.immersed().ok_or("no immersed body")?;
    let (mx, my) = body.forced_mask();
    let shape = ndarray::arr1(&body.circle().shape());
    let target = immersed_forcing(body, s.ux.view(), s.uy.view(), shape.view())?;
    let mut residual = 0.0f64;
    for (m, u, t) in [(&mx, &s.ux, &target.0), (&my, &s.uy, &target.1)] {
        for ((m, u), t) in m.iter().zip(u).zip(t) {
            if *m == 1.0 {
                residual = residual.max((u - t).abs());
            }
        }
    }
    println!(
        "2D-1 cpd {cpd} {scheme:?}: steps {} t {:.2} steady {} | cD {:.5} cL {:.6} dp {:.5} | CV cD {:.5} cL {:.6} | residual/Um {:.3e}",
        r.run.steps,
        r.run.time,
        r.run.steady,
        r.values[0],
        r.values[1],
        r.values[2],
        r.control_volume[0],
        r.control_volume[1],
        residual / DFG_2D1.um
    );
    Ok(())
}

fn periodic(cpd: usize, scheme: ForcingScheme) -> Result<()> {
    let mut case = Dfg2d2::new(cpd)?;
    case.channel = channel(case.channel, scheme);
    let r = case.run()?;
    println!(
        "2D-2 cpd {cpd} {scheme:?}: St {:.4} max cD {:.4} max cL {:.4} (CV max cD {:.4} max cL {:.4}) periodic {}",
        r.strouhal, r.cd_max, r.cl_max, r.cd_max_cv, r.cl_max_cv, r.periodic
    );
    Ok(())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: dfg_immersed 2d1|2d2 CPD direct|consistent";
    let [case, cpd, scheme] = args.as_slice() else {
        return Err(usage.into());
    };
    let cpd: usize = cpd.parse()?;
    let scheme = match scheme.as_str() {
        "direct" => ForcingScheme::Direct,
        "consistent" => ForcingScheme::ProjectionConsistent,
        _ => return Err(usage.into()),
    };
    match case.as_str() {
        "2d1" => steady(cpd, scheme),
        "2d2" => periodic(cpd, scheme),
        _ => Err(usage.into()),
    }
}
