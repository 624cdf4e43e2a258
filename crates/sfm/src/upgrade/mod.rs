//! Upgrading the projective model to a metric one (§3.4, "Upgrading the reconstruction to
//! metric"): a projective reconstruction is defined up to a 4×4 homography; the dual absolute
//! quadric `Ω*` (eqs. 22–23), found from the priors on the intrinsics (eqs. 24–26), gives the
//! upgrade `T` with `P_M = P T⁻¹`, `M_M = T M` (eq. 27). Under critical motion the images do not
//! determine `Ω*`, so several metric frames are candidates and the full metric adjustment decides.
//!
//! - `selfcal/`: the linear self-calibration with the DAQ (eqs. 22–27, ν re-weighting, the prior
//!   means estimated jointly, critical motion detected) and eq. 26 for a given focal length
//!   (`selfcal/known.rs`); pure linear algebra on the cameras, no model types.
//! - `transform.rs`: applying `T` to the model (eq. 27): the cameras decomposed into `K [R | t]`,
//!   the mirror frame turned so the points are in front, one camera per intrinsics group; a prior
//!   fallback (the quasi-Euclidean frame of the initial pair, `K = K_N`) when the linear estimate
//!   is unusable or its focal length implausible; the [`transform::SelfCalibrationReport`].
//! - `hypotheses.rs`: the focal hypotheses under critical motion: the minima of the absolute
//!   quadric's residual over the focal length (0.2–5 × (w + h)), and the median two-view focal
//!   length of the best verified pairs (Bougnoux 1998).
//! - `guard/`: the checks an adjusted candidate frame must pass (observations removed, plausible
//!   focal length, RMS against the projective model, points in front), the candidate loop's judge
//!   (`first_sound`, `best_sound`, `challenge` for a frame that contests the kept one), also
//!   applied to the adjustments after the frame (`collapsed`: a step whose adjustment removes too
//!   many observations is undone), and the warnings that the focal length is undetermined (another
//!   frame fits about as well, the camera only translates, the focal profile is flat).
//! - `frame.rs`: the metric frame of one start: every candidate (self-calibration, a known
//!   calibration, the priors, the focal hypotheses, the two-view focal length) given the full
//!   metric adjustment (`metric/ba.rs`) and judged, the probes of a camera that only translates,
//!   and the descent along the kept frame's focal profile (`metric/profile.rs`).

pub(crate) mod frame;
pub mod guard;
pub(crate) mod hypotheses;
pub mod selfcal;
pub mod transform;
