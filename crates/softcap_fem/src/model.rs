//! Whole-mesh elastic models: the corotational (λ, α) model of bickel2009 §3 with per-element
//! parameters and an optional strain-dependent parameter hook, and the stable neo-Hookean model.

use crate::element::{
    CorotationalStepFrame, Matrix12, StiffnessKind, TetGeometry, corotated_strain,
    corotational_forces, corotational_linearization, corotational_step_differential,
    corotational_step_frame, corotational_step_warped_product, corotational_tangent, strain_voigt,
    tet_geometries, warped_stiffness,
};
use crate::neohookean::{neohookean_energy, neohookean_forces, neohookean_tangent};
use crate::{FemError, LinearParams, NeoHookeanParams};
use nalgebra::{Matrix3, Vector3, Vector6};
use softcap_mesh::TetMesh;
use std::sync::Arc;

/// A tet-mesh elastic model as the solvers see it.
pub trait ElasticModel {
    /// Rest positions X \[m\].
    fn rest_positions(&self) -> &[Vector3<f64>];
    /// Precomputed rest geometry of every element.
    fn elements(&self) -> &[TetGeometry];
    /// Internal forces of element `e` at positions `x` (per element node).
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4];
    /// Element matrix of element `e` at `x`.
    fn element_matrix(&self, e: usize, x: &[Vector3<f64>], kind: StiffnessKind) -> Matrix12;
    /// Total elastic energy if the model is hyperelastic with fixed parameters.
    fn energy(&self, x: &[Vector3<f64>]) -> Option<f64>;
    /// Whether [`Self::element_matrix`] of this `kind` is symmetric. Default `true` (the element
    /// matrices of a hyperelastic model are energy Hessians; the warped matrix R K Rᵀ is symmetric
    /// for a symmetric K). A model answering `false` gets its system matrix assembled in full and
    /// factored by sparse LU ([`crate::SparseCholesky::factor_general`]) instead of a symmetric
    /// factorization of its lower triangle, which would solve with another matrix.
    fn tangent_is_symmetric(&self, _kind: StiffnessKind) -> bool {
        true
    }

    /// Called at the start of every equilibrium iteration with the current positions; a model with
    /// strain-dependent parameters updates them here (bickel2009 §3.4). Default: nothing.
    fn update_state(&mut self, _x: &[Vector3<f64>]) {}

    /// Identity of the model's current elastic state, for caches of solvers: two calls that
    /// return the same `Some(id)` — on this model or a clone of it — compute bitwise the same
    /// forces and energy at the same positions. A model must hand out a new id whenever its
    /// parameters (or anything else its forces depend on besides the positions) change. Default:
    /// `None` (nothing is cached across calls).
    fn state_id(&self) -> Option<u64> {
        None
    }

    /// Number of nodes.
    fn num_nodes(&self) -> usize {
        self.rest_positions().len()
    }

    /// Global internal force vector f_int(x) (assembled in element order: deterministic).
    fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); self.num_nodes()];
        for (e, geom) in self.elements().iter().enumerate() {
            let f = self.element_forces(e, x);
            for a in 0..4 {
                out[geom.nodes[a]] += f[a];
            }
        }
        out
    }

    /// f_int(x) and the energy (as [`Self::energy`]) from one pass over the elements, for line
    /// searches whose accepted trial point becomes the next iterate. Default: the two calls.
    fn forces_and_energy(&self, x: &[Vector3<f64>]) -> (Vec<Vector3<f64>>, Option<f64>) {
        (self.internal_forces(x), self.energy(x))
    }

    /// Forces and element matrices of the elements `first .. first + forces.len()` at `x`, in
    /// one pass (what every equilibrium iteration needs; `forces` and `matrices` have the same
    /// length). Returns Σ Ψ_e of those elements when the model is hyperelastic and the pass
    /// produced it, `None` otherwise (callers then use [`Self::energy`]).
    ///
    /// The default calls [`Self::element_forces`] and [`Self::element_matrix`]; models override
    /// it to share the element kinematics (one polar decomposition per element) and to evaluate
    /// elements in parallel. Each element's values must not depend on how the range is split, so
    /// that assembly (serial, in element order) stays bitwise deterministic.
    fn linearize_elements(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        matrices: &mut [Matrix12],
    ) -> Option<f64> {
        for (k, (f, m)) in forces.iter_mut().zip(matrices.iter_mut()).enumerate() {
            *f = self.element_forces(first + k, x);
            *m = self.element_matrix(first + k, x, kind);
        }
        None
    }

    /// Forces of the elements `first .. first + forces.len()` at `x` (as
    /// [`Self::linearize_elements`]) and, when `v` is given, the products K_e v_e of their
    /// element matrices of `kind` at `x` with the nodal velocities `v` (the stiffness-proportional
    /// Rayleigh damping force β K_e v_e without β; `products` untouched otherwise). No element
    /// matrix is returned: this is the pass of a Newton update that reuses a factored system
    /// matrix and needs only its residual. Same element-order contract as
    /// [`Self::linearize_elements`]; the values equal its forces and K_e v_e to round-off.
    ///
    /// The default forms K_e ([`Self::element_matrix`]); models override it to skip the 12×12
    /// matrix.
    fn element_forces_products(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        v: Option<&[Vector3<f64>]>,
        kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        products: &mut [[Vector3<f64>; 4]],
    ) {
        for (k, (f, p)) in forces.iter_mut().zip(products.iter_mut()).enumerate() {
            let e = first + k;
            *f = self.element_forces(e, x);
            if let Some(v) = v {
                *p = element_product(
                    &self.element_matrix(e, x, kind),
                    &self.elements()[e].nodes,
                    v,
                );
            }
        }
    }

    /// The exact derivative of the element pass of a dynamic step's residual — f_int(x) +
    /// β Σ_e K_e(x) v_e with element matrices of `kind` and v = v(x) of the integrator (∂v/∂x =
    /// `cv`) — at positions `x` and velocities `v`, kept per element for products with any
    /// number of directions ([`StepTangent::apply`]; what
    /// [`crate::DynamicSolver::step_sensitivities`] iterates with). Default `None`: not
    /// available (the caller differences the residual instead).
    fn step_tangent(
        &self,
        _x: &[Vector3<f64>],
        _v: &[Vector3<f64>],
        _kind: StiffnessKind,
        _beta: f64,
        _cv: f64,
    ) -> Option<StepTangent> {
        None
    }
}

/// The per-element state of [`ElasticModel::step_tangent`] (corotational elements with warped
/// element matrices: [`CorotationalStepFrame`]).
#[derive(Clone, Debug)]
pub struct StepTangent {
    frames: Vec<CorotationalStepFrame>,
}

/// One element's share of a [`StepTangent`] product ([`corotational_step_differential`],
/// [`corotational_step_warped_product`]).
type ElementKernel =
    fn(&TetGeometry, &CorotationalStepFrame, &[Vector3<f64>; 4]) -> [Vector3<f64>; 4];

impl StepTangent {
    /// The products of the tangent with each of `directions` (nodal fields; the elements of
    /// `elements`, those the tangent was built on), summed per node into `out` (one field per
    /// direction, overwritten): Σ_e of [`corotational_step_differential`].
    pub fn apply(
        &self,
        elements: &[TetGeometry],
        directions: &[&[Vector3<f64>]],
        out: &mut [Vec<Vector3<f64>>],
    ) {
        self.accumulate(elements, directions, out, corotational_step_differential);
    }

    /// The warped products Σ_e K_e w_e (K_e = R K_e Rᵀ at the tangent's state) of each of
    /// `fields`, summed per node into `out` ([`corotational_step_warped_product`]).
    pub fn warped_products(
        &self,
        elements: &[TetGeometry],
        fields: &[&[Vector3<f64>]],
        out: &mut [Vec<Vector3<f64>>],
    ) {
        self.accumulate(elements, fields, out, corotational_step_warped_product);
    }

    /// Σ_e `element`(g_e, frame_e, field_e) per node for every field: elements in chunks,
    /// possibly in parallel, accumulated serially in element order (the same bits on any number
    /// of threads).
    fn accumulate(
        &self,
        elements: &[TetGeometry],
        fields: &[&[Vector3<f64>]],
        out: &mut [Vec<Vector3<f64>>],
        element: ElementKernel,
    ) {
        let nd = fields.len();
        for (o, d) in out.iter_mut().zip(fields) {
            o.clear();
            o.resize(d.len(), Vector3::zeros());
        }
        let n_el = elements.len().min(self.frames.len());
        let chunk = ELEMENT_CHUNK.min(n_el.max(1));
        let mut buf = vec![[Vector3::zeros(); 4]; chunk * nd.max(1)];
        for start in (0..n_el).step_by(chunk) {
            let len = chunk.min(n_el - start);
            let one = |k: usize, slot: &mut [[Vector3<f64>; 4]]| {
                let (g, frame) = (&elements[start + k], &self.frames[start + k]);
                for (d, field) in fields.iter().enumerate() {
                    let fe = std::array::from_fn(|a| field[g.nodes[a]]);
                    slot[d] = element(g, frame, &fe);
                }
            };
            let slots = &mut buf[..len * nd];
            if serial_loop(len) || nd == 0 {
                for (k, slot) in slots.chunks_mut(nd.max(1)).enumerate() {
                    one(k, slot);
                }
            } else {
                use rayon::prelude::*;
                slots
                    .par_chunks_mut(nd)
                    .enumerate()
                    .for_each(|(k, slot)| one(k, slot));
            }
            for (k, g) in elements[start..start + len].iter().enumerate() {
                for (d, o) in out.iter_mut().enumerate() {
                    let df = &slots[k * nd + d];
                    for q in 0..4 {
                        o[g.nodes[q]] += df[q];
                    }
                }
            }
        }
    }
}

/// K_e v_e of a 12×12 element matrix with the velocities of its nodes, per node.
pub(crate) fn element_product(
    k: &Matrix12,
    nodes: &[usize; 4],
    v: &[Vector3<f64>],
) -> [Vector3<f64>; 4] {
    let mut ve = nalgebra::SVector::<f64, 12>::zeros();
    for q in 0..4 {
        ve.fixed_rows_mut::<3>(3 * q).copy_from(&v[nodes[q]]);
    }
    let kv = k * ve;
    std::array::from_fn(|q| kv.fixed_rows::<3>(3 * q).into_owned())
}

/// A process-wide fresh id for [`ElasticModel::state_id`] (ids are never reused, so a cache
/// keyed on one cannot confuse two models, or two states of one model).
pub(crate) fn fresh_state_id() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// Elements per chunk of the parallel element loops: bounds the scratch memory (a chunk of 12×12
/// element matrices is ≈ 4.7 MB) while keeping rayon's per-task overhead negligible.
pub(crate) const ELEMENT_CHUNK: usize = 4096;

/// Element loops shorter than this run serially on the calling thread: handing a few hundred
/// microseconds of work to the rayon pool costs more in wake-ups (a futex round trip per pass) than
/// it saves — a 5-tet model spent most of its time in them. The values are the same bits either way.
pub(crate) const PARALLEL_MIN_ELEMENTS: usize = 256;

thread_local! {
    /// Whether this thread's element loops run serially ([`with_serial_element_loops`]).
    static SERIAL_ELEMENT_LOOPS: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f` with the element loops of this thread serial if `serial` (else as they are): for
/// callers that already keep every thread busy with independent work — e.g. the segments of a
/// fit, one simulation per rayon task (`softcap_tissue::fit_dynamic::Forward`) — where nested
/// element tasks only add wake-ups and let a thread waiting on one of them take up another
/// simulation, delaying the first. The values are the same bits either way.
pub fn with_serial_element_loops<T>(serial: bool, f: impl FnOnce() -> T) -> T {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            SERIAL_ELEMENT_LOOPS.with(|s| s.set(self.0));
        }
    }
    let _restore = Restore(SERIAL_ELEMENT_LOOPS.with(|s| s.replace(serial || s.get())));
    f()
}

/// Whether an element loop over `len` elements runs serially on the calling thread (short, see
/// [`PARALLEL_MIN_ELEMENTS`], or inside [`with_serial_element_loops`]).
fn serial_loop(len: usize) -> bool {
    len < PARALLEL_MIN_ELEMENTS || SERIAL_ELEMENT_LOOPS.with(|s| s.get())
}

/// `f(k, &mut buf[k])` for every k, in parallel for long buffers (see [`PARALLEL_MIN_ELEMENTS`]).
pub(crate) fn fill_elements<T: Send>(buf: &mut [T], f: impl Fn(usize, &mut T) + Sync) {
    if serial_loop(buf.len()) {
        for (k, v) in buf.iter_mut().enumerate() {
            f(k, v);
        }
    } else {
        use rayon::prelude::*;
        buf.par_iter_mut().enumerate().for_each(|(k, v)| f(k, v));
    }
}

/// `element(k, &mut forces[k], &mut matrices[k])` for every k, in parallel for long ranges (see
/// [`PARALLEL_MIN_ELEMENTS`]): the loop of a one-pass [`ElasticModel::linearize_elements`] (and,
/// with per-node products in place of matrices, of [`ElasticModel::element_forces_products`]).
pub(crate) fn fill_linearization<T: Send>(
    forces: &mut [[Vector3<f64>; 4]],
    matrices: &mut [T],
    element: impl Fn(usize, &mut [Vector3<f64>; 4], &mut T) + Sync,
) {
    if serial_loop(forces.len()) {
        for (k, (f, m)) in forces.iter_mut().zip(matrices.iter_mut()).enumerate() {
            element(k, f, m);
        }
    } else {
        use rayon::prelude::*;
        forces
            .par_iter_mut()
            .zip(matrices.par_iter_mut())
            .enumerate()
            .for_each(|(k, (f, m))| element(k, f, m));
    }
}

/// Σ over elements of `per_element(e)` in element order, with the per-element values computed in
/// parallel: bitwise the same as the serial sum for any number of threads.
fn ordered_parallel_sum(n: usize, per_element: impl Fn(usize) -> f64 + Sync) -> f64 {
    let mut buf = vec![0.0; ELEMENT_CHUNK.min(n)];
    let mut total = 0.0;
    for start in (0..n).step_by(ELEMENT_CHUNK) {
        let len = ELEMENT_CHUNK.min(n - start);
        fill_elements(&mut buf[..len], |k, v| *v = per_element(start + k));
        for v in &buf[..len] {
            total += v;
        }
    }
    total
}

/// (f_int(x), Σ_e Ψ_e) from one parallel pass of `per_element(e) = (forces, energy)`, both
/// accumulated serially in element order (the bits of the serial loops).
fn ordered_parallel_forces_energy(
    geometry: &[TetGeometry],
    num_nodes: usize,
    per_element: impl Fn(usize) -> ([Vector3<f64>; 4], f64) + Sync,
) -> (Vec<Vector3<f64>>, f64) {
    let n = geometry.len();
    let mut out = vec![Vector3::zeros(); num_nodes];
    let mut total = 0.0;
    let mut buf = vec![([Vector3::zeros(); 4], 0.0); ELEMENT_CHUNK.min(n)];
    for start in (0..n).step_by(ELEMENT_CHUNK) {
        let len = ELEMENT_CHUNK.min(n - start);
        fill_elements(&mut buf[..len], |k, v| *v = per_element(start + k));
        for (k, (f, w)) in buf[..len].iter().enumerate() {
            let nodes = geometry[start + k].nodes;
            for a in 0..4 {
                out[nodes[a]] += f[a];
            }
            total += w;
        }
    }
    (out, total)
}

/// f_int(x) = Σ_e (element forces) with the element forces computed in parallel and accumulated
/// serially in element order (the same bits as the serial default of
/// [`ElasticModel::internal_forces`]).
pub(crate) fn ordered_parallel_forces(
    geometry: &[TetGeometry],
    num_nodes: usize,
    element_forces: impl Fn(usize) -> [Vector3<f64>; 4] + Sync,
) -> Vec<Vector3<f64>> {
    let n = geometry.len();
    let mut out = vec![Vector3::zeros(); num_nodes];
    let mut buf = vec![[Vector3::zeros(); 4]; ELEMENT_CHUNK.min(n)];
    for start in (0..n).step_by(ELEMENT_CHUNK) {
        let len = ELEMENT_CHUNK.min(n - start);
        fill_elements(&mut buf[..len], |k, f| *f = element_forces(start + k));
        for (k, f) in buf[..len].iter().enumerate() {
            let nodes = geometry[start + k].nodes;
            for a in 0..4 {
                out[nodes[a]] += f[a];
            }
        }
    }
    out
}

/// Strain-dependent parameters p_e = p_e(ε_e) (bickel2009 eq. 8 is one such function: an RBF in
/// strain space per element). `strain` is the corotated Voigt strain (ε_xx, ε_yy, ε_zz, γ_xy, γ_xz,
/// γ_yz) of [`crate::strain_voigt`].
pub trait StrainDependentParams: Send + Sync {
    /// Parameters of `element` at `strain`.
    fn params(&self, element: usize, strain: &Vector6<f64>) -> LinearParams;
}

impl<F> StrainDependentParams for F
where
    F: Fn(usize, &Vector6<f64>) -> LinearParams + Send + Sync,
{
    fn params(&self, element: usize, strain: &Vector6<f64>) -> LinearParams {
        self(element, strain)
    }
}

/// Linear corotational tet model with per-element (λ_e, α_e) (bickel2009 §3.2, eq. 7).
#[derive(Clone)]
pub struct CorotationalModel {
    rest: Vec<Vector3<f64>>,
    geometry: Vec<TetGeometry>,
    params: Vec<LinearParams>,
    hook: Option<Arc<dyn StrainDependentParams>>,
    /// [`ElasticModel::state_id`]: renewed by every change of `params` or `hook`.
    state_id: u64,
}

impl std::fmt::Debug for CorotationalModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CorotationalModel")
            .field("nodes", &self.rest.len())
            .field("elements", &self.geometry.len())
            .field("strain_dependent", &self.hook.is_some())
            .finish()
    }
}

impl CorotationalModel {
    /// Model over `mesh` with per-element parameters (one per tet, each validated).
    pub fn new(mesh: &TetMesh, params: Vec<LinearParams>) -> Result<Self, FemError> {
        let geometry = tet_geometries(&mesh.vertices, &mesh.tets)?;
        if params.len() != geometry.len() {
            return Err(FemError::LengthMismatch {
                what: "per-element parameters",
                expected: geometry.len(),
                got: params.len(),
            });
        }
        for (e, p) in params.iter().enumerate() {
            p.validate(e)?;
        }
        Ok(Self {
            rest: mesh.vertices.clone(),
            geometry,
            params,
            hook: None,
            state_id: fresh_state_id(),
        })
    }

    /// Homogeneous model.
    pub fn homogeneous(mesh: &TetMesh, p: LinearParams) -> Result<Self, FemError> {
        Self::new(mesh, vec![p; mesh.tets.len()])
    }

    /// Attaches a strain-dependent parameter function, applied at every equilibrium iteration.
    pub fn with_strain_dependence(mut self, hook: Arc<dyn StrainDependentParams>) -> Self {
        self.hook = Some(hook);
        self.state_id = fresh_state_id();
        self
    }

    /// Current per-element parameters.
    pub fn params(&self) -> &[LinearParams] {
        &self.params
    }

    /// Replaces the per-element parameters (not validated: a fitter may probe outside the valid
    /// region; [`LinearParams::validate`] is available).
    pub fn set_params(&mut self, params: &[LinearParams]) -> Result<(), FemError> {
        if params.len() != self.params.len() {
            return Err(FemError::LengthMismatch {
                what: "per-element parameters",
                expected: self.params.len(),
                got: params.len(),
            });
        }
        self.params.copy_from_slice(params);
        self.state_id = fresh_state_id();
        Ok(())
    }

    /// Element rotations R_e (polar decomposition of F_e) at `x`.
    pub fn rotations(&self, x: &[Vector3<f64>]) -> Vec<Matrix3<f64>> {
        self.geometry
            .iter()
            .map(|g| corotated_strain(&g.deformation_gradient(x)).0)
            .collect()
    }

    /// Corotated Voigt strains ε_e at `x` (the strain-space coordinates of bickel2009 §3.3).
    pub fn strains(&self, x: &[Vector3<f64>]) -> Vec<Vector6<f64>> {
        self.geometry
            .iter()
            .map(|g| strain_voigt(&corotated_strain(&g.deformation_gradient(x)).1))
            .collect()
    }
}

impl ElasticModel for CorotationalModel {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        &self.rest
    }
    fn elements(&self) -> &[TetGeometry] {
        &self.geometry
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        corotational_forces(&self.geometry[e], &self.params[e], x)
    }
    fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        ordered_parallel_forces(&self.geometry, self.rest.len(), |e| {
            corotational_forces(&self.geometry[e], &self.params[e], x)
        })
    }
    fn forces_and_energy(&self, x: &[Vector3<f64>]) -> (Vec<Vector3<f64>>, Option<f64>) {
        let (f, energy) = ordered_parallel_forces_energy(&self.geometry, self.rest.len(), |e| {
            let g = &self.geometry[e];
            let (r, eps) = corotated_strain(&g.deformation_gradient(x));
            let sigma = crate::element::linear_stress(&self.params[e], &eps);
            let p = r * sigma * g.volume_m3;
            (
                [
                    p * g.grads[0],
                    p * g.grads[1],
                    p * g.grads[2],
                    p * g.grads[3],
                ],
                0.5 * g.volume_m3 * (sigma.component_mul(&eps)).sum(),
            )
        });
        (f, self.hook.is_none().then_some(energy))
    }
    fn linearize_elements(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        matrices: &mut [Matrix12],
    ) -> Option<f64> {
        use rayon::prelude::*;
        let mut energies = vec![0.0; forces.len()];
        let element =
            |k: usize, ((f, m), w): ((&mut [Vector3<f64>; 4], &mut Matrix12), &mut f64)| {
                let (g, p) = (&self.geometry[first + k], &self.params[first + k]);
                match kind {
                    StiffnessKind::Warped => (*f, *w) = corotational_linearization(g, p, x, m),
                    StiffnessKind::Consistent => {
                        *f = corotational_forces(g, p, x);
                        *m = corotational_tangent(g, p, x);
                    }
                }
            };
        if serial_loop(forces.len()) {
            for (k, item) in forces
                .iter_mut()
                .zip(matrices.iter_mut())
                .zip(energies.iter_mut())
                .enumerate()
            {
                element(k, item);
            }
        } else {
            forces
                .par_iter_mut()
                .zip(matrices.par_iter_mut())
                .zip(energies.par_iter_mut())
                .enumerate()
                .for_each(|(k, item)| element(k, item));
        }
        // Energy only for fixed parameters and when it came out of the pass.
        (self.hook.is_none() && kind == StiffnessKind::Warped).then(|| energies.iter().sum())
    }
    /// For the warped matrix without forming it: R K_e Rᵀ v_e is the corotational force of the
    /// velocity field, f_a = V R σ(sym(Rᵀ Ḟ)) g_a with Ḟ = Σ_a v_a g_aᵀ (R K_e Rᵀ applied to v is
    /// K_e applied to the unrotated velocities Rᵀ v, whose gradient is Rᵀ Ḟ, then rotated back;
    /// bickel2009 eq. 7, 10), from the one polar decomposition the forces need. The consistent
    /// tangent is formed as in the default.
    fn element_forces_products(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        v: Option<&[Vector3<f64>]>,
        kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        products: &mut [[Vector3<f64>; 4]],
    ) {
        fill_linearization(forces, products, |k, f, kv| {
            let (g, p) = (&self.geometry[first + k], &self.params[first + k]);
            let (r, eps) = corotated_strain(&g.deformation_gradient(x));
            let pm = r * crate::element::linear_stress(p, &eps) * g.volume_m3;
            *f = std::array::from_fn(|a| pm * g.grads[a]);
            let Some(v) = v else { return };
            *kv = match kind {
                StiffnessKind::Warped => {
                    let rate = r.transpose() * g.deformation_gradient(v);
                    let rate = (rate + rate.transpose()) * 0.5;
                    let pv = r * crate::element::linear_stress(p, &rate) * g.volume_m3;
                    std::array::from_fn(|a| pv * g.grads[a])
                }
                StiffnessKind::Consistent => {
                    element_product(&corotational_tangent(g, p, x), &g.nodes, v)
                }
            };
        });
    }
    /// [`CorotationalStepFrame`] per element for the warped matrices; `None` for the consistent
    /// ones and for strain-dependent parameters (which change with x).
    fn step_tangent(
        &self,
        x: &[Vector3<f64>],
        v: &[Vector3<f64>],
        kind: StiffnessKind,
        beta: f64,
        cv: f64,
    ) -> Option<StepTangent> {
        if kind != StiffnessKind::Warped || self.hook.is_some() {
            return None;
        }
        let mut frames = vec![CorotationalStepFrame::default(); self.geometry.len()];
        fill_elements(&mut frames, |e, f| {
            *f = corotational_step_frame(&self.geometry[e], &self.params[e], x, v, beta, cv);
        });
        Some(StepTangent { frames })
    }
    fn element_matrix(&self, e: usize, x: &[Vector3<f64>], kind: StiffnessKind) -> Matrix12 {
        let g = &self.geometry[e];
        match kind {
            StiffnessKind::Warped => {
                let (r, _) = corotated_strain(&g.deformation_gradient(x));
                warped_stiffness(g, &self.params[e], &r)
            }
            StiffnessKind::Consistent => corotational_tangent(g, &self.params[e], x),
        }
    }
    fn energy(&self, x: &[Vector3<f64>]) -> Option<f64> {
        if self.hook.is_some() {
            return None; // Cauchy-elastic only (thesis §7.4.3): no potential.
        }
        Some(ordered_parallel_sum(self.geometry.len(), |e| {
            let g = &self.geometry[e];
            let (_, eps) = corotated_strain(&g.deformation_gradient(x));
            let sigma = crate::element::linear_stress(&self.params[e], &eps);
            0.5 * g.volume_m3 * (sigma.component_mul(&eps)).sum()
        }))
    }
    fn update_state(&mut self, x: &[Vector3<f64>]) {
        if let Some(hook) = self.hook.clone() {
            for (e, g) in self.geometry.iter().enumerate() {
                let eps = strain_voigt(&corotated_strain(&g.deformation_gradient(x)).1);
                self.params[e] = hook.params(e, &eps);
            }
            self.state_id = fresh_state_id();
        }
    }
    fn state_id(&self) -> Option<u64> {
        Some(self.state_id)
    }
}

/// Stable neo-Hookean tet model (Smith et al. 2018) with per-element parameters.
#[derive(Clone, Debug)]
pub struct NeoHookeanModel {
    rest: Vec<Vector3<f64>>,
    geometry: Vec<TetGeometry>,
    params: Vec<NeoHookeanParams>,
    /// Geometry the elastic energy is evaluated on when it differs from the rest geometry: the
    /// plastic configuration of [`crate::PlasticNeoHookeanModel`] (gradients F_p⁻ᵀ g_a, volume
    /// V det F_p, so that F = F_e = F F_p⁻¹). `None`: the rest geometry.
    material: Option<Vec<TetGeometry>>,
}

impl NeoHookeanModel {
    /// Model over `mesh` with one parameter set per tet.
    pub fn new(mesh: &TetMesh, params: Vec<NeoHookeanParams>) -> Result<Self, FemError> {
        let geometry = tet_geometries(&mesh.vertices, &mesh.tets)?;
        if params.len() != geometry.len() {
            return Err(FemError::LengthMismatch {
                what: "per-element parameters",
                expected: geometry.len(),
                got: params.len(),
            });
        }
        Ok(Self {
            rest: mesh.vertices.clone(),
            geometry,
            params,
            material: None,
        })
    }

    /// Homogeneous model.
    pub fn homogeneous(mesh: &TetMesh, p: NeoHookeanParams) -> Result<Self, FemError> {
        Self::new(mesh, vec![p; mesh.tets.len()])
    }

    /// Per-element parameters.
    pub fn params(&self) -> &[NeoHookeanParams] {
        &self.params
    }

    /// The geometry the element kernels use (rest geometry unless a plastic one is set).
    pub(crate) fn material_geometry(&self) -> &[TetGeometry] {
        self.material.as_deref().unwrap_or(&self.geometry)
    }

    /// Mutable material geometry (created from the rest geometry on first use).
    pub(crate) fn material_geometry_mut(&mut self) -> &mut [TetGeometry] {
        self.material.get_or_insert_with(|| self.geometry.clone())
    }
}

impl ElasticModel for NeoHookeanModel {
    fn rest_positions(&self) -> &[Vector3<f64>] {
        &self.rest
    }
    fn elements(&self) -> &[TetGeometry] {
        &self.geometry
    }
    fn element_forces(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        neohookean_forces(&self.material_geometry()[e], &self.params[e], x)
    }
    fn element_matrix(&self, e: usize, x: &[Vector3<f64>], _kind: StiffnessKind) -> Matrix12 {
        neohookean_tangent(&self.material_geometry()[e], &self.params[e], x)
    }
    fn energy(&self, x: &[Vector3<f64>]) -> Option<f64> {
        let g = self.material_geometry();
        Some(ordered_parallel_sum(g.len(), |e| {
            neohookean_energy(&g[e], &self.params[e], x)
        }))
    }
    fn internal_forces(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let g = self.material_geometry();
        ordered_parallel_forces(g, self.rest.len(), |e| {
            neohookean_forces(&g[e], &self.params[e], x)
        })
    }
    fn forces_and_energy(&self, x: &[Vector3<f64>]) -> (Vec<Vector3<f64>>, Option<f64>) {
        let g = self.material_geometry();
        let (f, energy) = ordered_parallel_forces_energy(g, self.rest.len(), |e| {
            (
                neohookean_forces(&g[e], &self.params[e], x),
                neohookean_energy(&g[e], &self.params[e], x),
            )
        });
        (f, Some(energy))
    }
    fn linearize_elements(
        &self,
        first: usize,
        x: &[Vector3<f64>],
        _kind: StiffnessKind,
        forces: &mut [[Vector3<f64>; 4]],
        matrices: &mut [Matrix12],
    ) -> Option<f64> {
        let g = self.material_geometry();
        fill_linearization(forces, matrices, |k, f, m| {
            let e = first + k;
            *f = neohookean_forces(&g[e], &self.params[e], x);
            *m = neohookean_tangent(&g[e], &self.params[e], x);
        });
        None
    }
}
