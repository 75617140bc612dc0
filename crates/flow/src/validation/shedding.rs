//! Vortex shedding read from a lift history: when the lift crosses its mean
//! upwards, the periods between those crossings, whether they have settled,
//! and the Strouhal number.

/// The shedding in a history of `(t, c_L)` samples.
///
/// An up-crossing is a pair of samples with `c_L(t_k) < c̄_L ≤ c_L(t_{k+1})`
/// (`c̄_L` the mean over the history), placed by linear interpolation:
///
/// ```text
/// t* = t_k + (c̄_L − c_L(t_k)) / (c_L(t_{k+1}) − c_L(t_k)) · (t_{k+1} − t_k)
/// ```
///
/// The periods are the differences of successive crossings; their mean is
/// `(t*_last − t*_first) / (crossings − 1)`, and the Strouhal number of a
/// body of length `D` in a stream of speed `U` is `D / (U T̄)`.
///
/// ```
/// use diffphys_flow::validation::Shedding;
///
/// // A lift of period 2 sampled every 0.1.
/// let t: Vec<f64> = (0..100).map(|k| 0.1 * k as f64).collect();
/// let lift: Vec<f64> = t.iter().map(|t| (std::f64::consts::PI * t).sin()).collect();
/// let s = Shedding::of(&t, &lift);
/// assert!((s.mean_period().unwrap() - 2.0).abs() < 1e-3);
/// assert!(s.settled(0.01));
/// assert!((s.strouhal(0.1, 1.0).unwrap() - 0.05).abs() < 1e-4);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct Shedding {
    /// The mean lift over the history.
    pub mean: f64,
    /// The times of the up-crossings of the mean.
    pub crossings: Vec<f64>,
    /// The periods between successive up-crossings.
    pub periods: Vec<f64>,
}

impl Shedding {
    /// The shedding of the lift `lift[k]` at times `t[k]` (the shorter of the
    /// two sets the length).
    pub fn of(t: &[f64], lift: &[f64]) -> Self {
        let n = t.len().min(lift.len());
        let (t, lift) = (&t[..n], &lift[..n]);
        let mean = lift.iter().sum::<f64>() / n.max(1) as f64;
        let crossings: Vec<f64> = (0..n.saturating_sub(1))
            .filter(|&k| lift[k] < mean && lift[k + 1] >= mean)
            .map(|k| t[k] + (mean - lift[k]) / (lift[k + 1] - lift[k]) * (t[k + 1] - t[k]))
            .collect();
        let periods = crossings.windows(2).map(|w| w[1] - w[0]).collect();
        Shedding {
            mean,
            crossings,
            periods,
        }
    }

    /// The mean period, `None` with fewer than two crossings.
    pub fn mean_period(&self) -> Option<f64> {
        let (first, last) = (self.crossings.first()?, self.crossings.last()?);
        (!self.periods.is_empty()).then(|| (last - first) / self.periods.len() as f64)
    }

    /// The Strouhal number `D / (U T̄)` of a body of length `diameter` in a
    /// stream of speed `speed`; `None` with fewer than two crossings.
    pub fn strouhal(&self, diameter: f64, speed: f64) -> Option<f64> {
        self.mean_period().map(|p| diameter / (p * speed))
    }

    /// Whether the shedding has settled: the last two periods agree to
    /// `rel_tol` of the last (`false` with fewer than two periods).
    pub fn settled(&self, rel_tol: f64) -> bool {
        match self.periods[..] {
            [.., b, a] => (a - b).abs() / a < rel_tol,
            _ => false,
        }
    }
}
