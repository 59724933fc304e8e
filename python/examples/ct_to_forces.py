"""A CT label volume and a 3DXRD grain map going to forces.

The 77 spheres of the 3D DEM oedometer (fixtures/regression/oedometer3d_seed1,
exact forces known) are voxelised at 30 voxels per diameter into a label
volume, as a segmented tomography scan gives it. Their stresses come as a
diffraction instrument reports them: an ImageD11 grain map (`.map`, quartz,
a random orientation per grain, UBIs to 9 digits) in the instrument's own
frame (turned 120° about a skew axis and shifted). `import_imaged11` turns
the map into stresses, `import_labels` finds grains, contacts and normals
in the volume, fits the transform between the frames and attaches the
stresses; `infer` gives the forces, compared with the DEM's. With `--vtk
FOLDER` the scene and forces are exported for ParaView; with `--picture
PNG` they are drawn offscreen with VTK (`pip install vtk`), the pipeline
docs/field.md gives for ParaView (spheres, contacts as tubes coloured by
force).

    python python/examples/ct_to_forces.py [--vtk out/] [--picture forces.png]
"""

import argparse
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

import grainforce as gf

REPO = Path(__file__).resolve().parents[2]
DEM = REPO / "fixtures" / "regression" / "oedometer3d_seed1"
VOXELS_PER_DIAMETER = 30


def voxelise(grains: pd.DataFrame, voxel: float, lo: np.ndarray, shape) -> np.ndarray:
    """Each voxel the label (DEM row + 1) of the sphere whose surface is
    relatively nearest, 0 outside every sphere: what a clean watershed gives."""
    labels = np.zeros(shape, dtype=np.uint16)
    best = np.full(shape, np.inf, dtype=np.float32)
    for row, g in enumerate(grains.itertuples()):
        centre = np.array([g.x, g.y, g.z])
        first = np.maximum(np.floor((centre - g.radius - lo) / voxel).astype(int), 0)
        last = np.minimum(np.ceil((centre + g.radius - lo) / voxel).astype(int) + 1, shape[::-1])
        zs, ys, xs = (np.arange(first[k], last[k]) for k in (2, 1, 0))
        z, y, x = np.meshgrid(zs, ys, xs, indexing="ij")
        d = np.sqrt(
            (lo[0] + voxel * x - centre[0]) ** 2
            + (lo[1] + voxel * y - centre[1]) ** 2
            + (lo[2] + voxel * z - centre[2]) ** 2
        ) / g.radius
        box = (slice(zs[0], zs[-1] + 1), slice(ys[0], ys[-1] + 1), slice(xs[0], xs[-1] + 1))
        inside = (d <= 1.0) & (d < best[box])
        labels[box][inside] = row + 1
        best[box][inside] = d[inside]
    return labels


def turned(grains: pd.DataFrame) -> pd.DataFrame:
    """The grains' positions and stresses in another instrument's frame."""
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    angle = np.radians(120.0)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rotation = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    shift = np.array([0.004, -0.002, 0.001])
    xyz = grains[["x", "y", "z"]].to_numpy() @ rotation.T + shift
    out = pd.DataFrame({"id": [f"xrd{i}" for i in grains["id"]]})
    out["x"], out["y"], out["z"] = xyz.T
    names = [["s_xx", "s_xy", "s_xz"], ["s_xy", "s_yy", "s_yz"], ["s_xz", "s_yz", "s_zz"]]
    for name in ["s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz"]:
        out[name] = 0.0
    for i, g in grains.iterrows():
        sigma = np.array([[g[n] for n in row] for row in names])
        s = rotation @ sigma @ rotation.T
        for (a, b), name in zip([(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)],
                                ["s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz"]):
            out.loc[i, name] = s[a, b]
    return out


# α-quartz: the cell ImageD11 is given and the constants of the `quartz`
# preset (GPa, IEEE axes x ∥ a; McSkimin et al. 1965).
QUARTZ_CELL = (4.9134, 4.9134, 5.4052, 90.0, 90.0, 120.0)
C11, C12, C13, C14, C33, C44 = 86.74, 6.99, 11.91, -17.91, 107.2, 57.94
VOIGT = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]


def busing_levy_b(cell) -> np.ndarray:
    """The B matrix of a cell (reciprocal vectors, crystal frame x ∥ a*)."""
    a, b, c = cell[:3]
    al, be, ga = np.radians(cell[3:])
    direct = np.array([
        [a, 0, 0],
        [b * np.cos(ga), b * np.sin(ga), 0],
        [c * np.cos(be), c * (np.cos(al) - np.cos(be) * np.cos(ga)) / np.sin(ga), 0],
    ])
    direct[2, 2] = np.sqrt(c * c - direct[2, 0] ** 2 - direct[2, 1] ** 2)
    recip = np.linalg.inv(direct).T  # rows a*, b*, c*
    la, lb, lc = np.linalg.norm(recip, axis=1)
    cos_al = recip[1] @ recip[2] / (lb * lc)
    cos_be = recip[0] @ recip[2] / (la * lc)
    cos_ga = recip[0] @ recip[1] / (la * lb)
    sin_ga = np.sqrt(1 - cos_ga**2)
    sin_be = np.sqrt(1 - cos_be**2)
    cos_alpha = np.cos(al)
    return np.array([
        [la, lb * cos_ga, lc * cos_be],
        [0, lb * sin_ga, -lc * sin_be * cos_alpha],
        [0, 0, 1 / c],
    ])


def quartz_compliance() -> np.ndarray:
    """S = C⁻¹ in Voigt form (engineering shears), IEEE axes, 1/Pa."""
    c66 = (C11 - C12) / 2
    c = np.array([
        [C11, C12, C13, C14, 0, 0],
        [C12, C11, C13, -C14, 0, 0],
        [C13, C13, C33, 0, 0, 0],
        [C14, -C14, 0, C44, 0, 0],
        [0, 0, 0, 0, C44, C14],
        [0, 0, 0, 0, C14, c66],
    ]) * 1e9
    return np.linalg.inv(c)


def write_imaged11_map(grains: pd.DataFrame, path: Path, seed: int = 7) -> None:
    """The grains' stresses as a 3DXRD grain map: for each grain a random
    orientation R, the crystal strain from the stress (Hooke's law in IEEE
    axes, turned 30° about c into ImageD11's x ∥ a*), the Biot stretch
    S = I + ε, F = R S and UBI = B0⁻¹ Fᵀ (ImageD11: F = UBIᵀ B0ᵀ)."""
    rng = np.random.default_rng(seed)
    b0_inv = np.linalg.inv(busing_levy_b(QUARTZ_CELL))
    compliance = quartz_compliance()
    turn = np.radians(30.0)
    ieee = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    names = [["s_xx", "s_xy", "s_xz"], ["s_xy", "s_yy", "s_yz"], ["s_xz", "s_yz", "s_zz"]]
    blocks = []
    for _, g in grains.iterrows():
        q = rng.normal(size=4)
        w, x, y, z = q / np.linalg.norm(q)
        rotation = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
        sigma_sample = np.array([[g[n] for n in row] for row in names])
        sigma = ieee @ rotation.T @ sigma_sample @ rotation @ ieee.T
        strain_voigt = compliance @ np.array([sigma[i, j] for i, j in VOIGT])
        strain = np.zeros((3, 3))
        for k, (i, j) in enumerate(VOIGT):
            strain[i, j] = strain[j, i] = strain_voigt[k] * (1.0 if i == j else 0.5)
        stretch = np.eye(3) + ieee.T @ strain @ ieee
        ubi = b0_inv @ (rotation @ stretch).T
        rows = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in ubi)
        position = 1e6 * np.array([g.x, g.y, g.z])  # µm
        blocks.append("#translation: " + " ".join(f"{v:.6g}" for v in position)
                      + "\n#npks 100\n#UBI:\n" + rows + "\n")
    path.write_text("\n".join(blocks))


def relerr_by_pair(scene_dir: Path, forces: pd.DataFrame, truth_dir: Path) -> float:
    """‖f − f_DEM‖ / ‖f_DEM‖ over contacts matched by their pair of bodies
    (labels are DEM rows + 1); a missed or a false contact counts whole."""
    def by_pair(contacts: pd.DataFrame, forces: pd.DataFrame, to_dem) -> dict:
        merged = contacts.merge(forces, left_on="id", right_on="contact")
        out = {}
        for c in merged.itertuples():
            a, b = to_dem(c.a), to_dem(c.b)
            f = np.array([c.f_x, c.f_y, c.f_z])
            key = (a, b) if a < b else (b, a)
            out[key] = out.get(key, 0) + (f if a < b else -f)
        return out

    text = {"id": str, "a": str, "b": str, "contact": str}
    dem_id = lambda v: v if not v.isdigit() else str(int(v))
    ct_id = lambda v: v if not v.isdigit() else str(int(v) - 1)
    truth = by_pair(pd.read_csv(truth_dir / "contacts.csv", dtype=text),
                    pd.read_csv(truth_dir / "forces.csv", dtype=text), dem_id)
    ours = by_pair(pd.read_csv(scene_dir / "contacts.csv", dtype=text), forces, ct_id)
    zero = np.zeros(3)
    num = sum(np.sum((ours.get(k, zero) - truth.get(k, zero)) ** 2) for k in set(truth) | set(ours))
    return float(np.sqrt(num / sum(np.sum(f**2) for f in truth.values())))


def ct_to_forces(vtk_dir=None, picture=None, verbose=True) -> dict:
    """The whole path; returns how far the map's stresses [Pa] and the
    forces (relerr) land from the DEM's."""
    say = print if verbose else (lambda *a: None)
    grains = pd.read_csv(DEM / "grains.csv", dtype={"id": str})
    voxel = 2 * grains["radius"].mean() / VOXELS_PER_DIAMETER
    xyz = grains[["x", "y", "z"]].to_numpy()
    r = grains["radius"].to_numpy()[:, None]
    lo, hi = (xyz - r).min(axis=0) - 2 * voxel, (xyz + r).max(axis=0) + 2 * voxel
    shape = tuple(int(np.ceil(v)) for v in ((hi - lo) / voxel)[::-1])
    labels = voxelise(grains, voxel, lo, shape)
    say(f"label volume {shape} (z, y, x), voxel {voxel:.3g} m, {labels.max()} grains")

    # The oedometer's walls are the planes x, y, z = 0 and the far faces,
    # known from the DEM's wall contacts (a CT user reads them off the scan).
    contacts = pd.read_csv(DEM / "contacts.csv", dtype={"b": str})
    walls = {}
    for name, axis in [("left", "x"), ("right", "x"), ("bottom", "y"), ("top", "y"),
                       ("back", "z"), ("front", "z")]:
        walls[name] = (axis, float(contacts.loc[contacts["b"] == name, axis].mean()))

    # The diffraction instrument's grain map, in its own frame.
    with tempfile.TemporaryDirectory() as tmp:
        write_imaged11_map(turned(grains), Path(tmp) / "grains.map")
        xrd = gf.import_imaged11(Path(tmp) / "grains.map", cell=QUARTZ_CELL, stiffness="quartz",
                                 grain_volume=1e-12)
    measured = xrd.to_frames()[0]
    stress = ["s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz"]
    off = np.abs(measured[stress].to_numpy() - turned(grains)[stress].to_numpy()).max()
    say(f"grain map: {xrd.n_grains} grains, stresses {off / 1e6:.1e} MPa from the DEM's")

    ct = gf.import_labels(labels, voxel, origin=list(lo), walls=walls, stresses=xrd)
    t = ct.transform
    say(f"{ct.scene.n_grains} grains, {ct.scene.n_contacts} contacts; stresses matched: "
        f"{t['matched']} grains, rotation {t['rotation_angle_degrees']:.2f}°, "
        f"rms {t['rms_distance']:.2e} m")
    result = gf.infer(ct.scene, method="qs", mu=0.5)
    with tempfile.TemporaryDirectory() as tmp:
        scene_dir = Path(tmp) / "scene"
        ct.save(scene_dir)
        error = relerr_by_pair(scene_dir, result.forces, DEM)
        say(f"forces against the DEM's: relerr {error:.4f}")
        if vtk_dir or picture:
            vtk_dir = Path(vtk_dir or Path(tmp) / "vtk")
            vtk_dir.mkdir(parents=True, exist_ok=True)
            result.save(vtk_dir / "forces.csv")
            binary = os.environ.get("GRAINFORCE_BIN") or shutil.which("grainforce")
            subprocess.run([binary, "-q", "export", "vtk", str(scene_dir), str(vtk_dir / "forces.csv"),
                            "-o", str(vtk_dir / "ct.vtp")], check=True)
            if picture:
                draw(vtk_dir / "ct.vtp", vtk_dir / "ct_contacts.vtp", picture)
                say(f"wrote {picture}")
    return {"map_stress_off": off, "relerr": error}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vtk", type=Path, help="folder for the ParaView files")
    parser.add_argument("--picture", type=Path, help="PNG drawn offscreen with VTK")
    args = parser.parse_args()
    ct_to_forces(args.vtk, args.picture)


def draw(grains_file: Path, contacts_file: Path, picture: Path) -> None:
    """docs/field.md's ParaView pipeline in plain VTK, offscreen."""
    import vtk

    def reader(path):
        r = vtk.vtkXMLPolyDataReader()
        r.SetFileName(str(path))
        r.Update()
        return r

    grains, contacts = reader(grains_file), reader(contacts_file)
    sphere = vtk.vtkSphereSource()
    sphere.SetThetaResolution(32)
    sphere.SetPhiResolution(16)
    sphere.SetRadius(1.0)
    grains.GetOutput().GetPointData().SetActiveScalars("radius")
    glyph = vtk.vtkGlyph3D()
    glyph.SetInputConnection(grains.GetOutputPort())
    glyph.SetSourceConnection(sphere.GetOutputPort())
    glyph.SetScaleModeToScaleByScalar()
    glyph.SetColorModeToColorByScale()
    glyph_mapper = vtk.vtkPolyDataMapper()
    glyph_mapper.SetInputConnection(glyph.GetOutputPort())
    glyph_mapper.ScalarVisibilityOff()
    glyph_actor = vtk.vtkActor()
    glyph_actor.SetMapper(glyph_mapper)
    glyph_actor.GetProperty().SetColor(0.82, 0.82, 0.85)
    glyph_actor.GetProperty().SetOpacity(0.18)

    data = contacts.GetOutput()
    magnitude = data.GetCellData().GetArray("force_magnitude")
    low, high = magnitude.GetRange()
    tube = vtk.vtkTubeFilter()
    tube.SetInputConnection(contacts.GetOutputPort())
    tube.SetRadius(0.000035)
    tube.SetNumberOfSides(16)
    table = vtk.vtkColorTransferFunction()
    # Weak contacts pale, strong ones dark red (matplotlib's YlOrRd, sampled).
    for k, colour in enumerate([(1.0, 0.93, 0.63), (0.99, 0.70, 0.30), (0.99, 0.31, 0.16),
                                (0.74, 0.0, 0.15), (0.40, 0.0, 0.05)]):
        table.AddRGBPoint(low + (high - low) * k / 4, *colour)
    tube_mapper = vtk.vtkPolyDataMapper()
    tube_mapper.SetInputConnection(tube.GetOutputPort())
    tube_mapper.SetScalarModeToUseCellFieldData()
    tube_mapper.SelectColorArray("force_magnitude")
    tube_mapper.SetLookupTable(table)
    tube_mapper.SetScalarRange(low, high)
    tube_actor = vtk.vtkActor()
    tube_actor.SetMapper(tube_mapper)

    bar = vtk.vtkScalarBarActor()
    bar.SetLookupTable(table)
    bar.SetTitle("force [N]")
    bar.SetNumberOfLabels(5)
    bar.SetWidth(0.12)
    bar.SetHeight(0.6)
    bar.SetPosition(0.85, 0.2)
    bar.UnconstrainedFontSizeOn()
    for text in (bar.GetTitleTextProperty(), bar.GetLabelTextProperty()):
        text.SetColor(0, 0, 0)
        text.SetFontSize(16)
        text.ShadowOff()

    renderer = vtk.vtkRenderer()
    renderer.SetBackground(1, 1, 1)
    for actor in (glyph_actor, tube_actor):
        renderer.AddActor(actor)
    renderer.AddViewProp(bar)
    window = vtk.vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.AddRenderer(renderer)
    window.SetSize(720, 560)
    camera = renderer.GetActiveCamera()
    camera.Azimuth(35)
    camera.Elevation(25)
    renderer.ResetCamera()
    camera.Zoom(1.3)
    window.Render()
    shot = vtk.vtkWindowToImageFilter()
    shot.SetInput(window)
    shot.Update()
    writer = vtk.vtkPNGWriter()
    writer.SetFileName(str(picture))
    writer.SetInputConnection(shot.GetOutputPort())
    writer.Write()


if __name__ == "__main__":
    main()
