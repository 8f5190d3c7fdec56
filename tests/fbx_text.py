"""Test helpers writing FBX text: a tree (rig.motion.fbx_tree.Node) as ASCII FBX 7.x in the FBX SDK's layout, and
a small skinned bar as an FBX 6.1 ASCII file in Maya 2009's layout, with what it should pose to."""
from __future__ import annotations

import base64

import numpy as np

from jiggle.rig.motion.fbx_tree import CLASS_SEP, Node


def ascii_fbx(nodes: list[Node], version: int) -> str:
    """The tree as ASCII FBX, as the FBX SDK writes it: `*N { a: ... }` arrays, "Class::Name" object names, bare
    letters for char values, base64 for embedded media (other raw bytes, FileId, left out as the SDK does)."""
    out = [f"; FBX {version // 1000}.{version % 1000 // 100}.0 project file", ""]

    def value(v, t):
        if t == "S":
            if CLASS_SEP in v:
                name, cls = v.split(CLASS_SEP, 1)
                v = f"{cls}::{name}"
            return '"' + v.replace('"', "&quot;") + '"'
        if t == "R":
            return '"' + base64.b64encode(v).decode() + '"'
        if t == "C":             # a letter (Maya: Shading: Y); Blender writes booleans 0/1 there, which ASCII spells T/F
            return chr(v) if chr(v).isalpha() else ("T" if v else "F")
        if t in "DF":
            return repr(float(v))
        return str(int(v))

    def emit(n: Node, depth: int):
        pad = "\t" * depth
        if "R" in n.types and n.name != "Content":    # FileId: the SDK leaves raw bytes out of ASCII files
            return
        if n.types and n.types[0] in "fdilbc":
            arr = n.props[0]
            vals = ",".join(repr(float(x)) if n.types[0] in "fd" else str(int(x)) for x in np.ravel(arr))
            out.append(f"{pad}{n.name}: *{np.size(arr)} {{")
            out.append(f"{pad}\ta: {vals}")
            out.append(f"{pad}}}")
            return
        line = f"{pad}{n.name}: " + ",".join(value(v, t) for v, t in zip(n.props, n.types))
        if n.children or not n.props:
            out.append(line + " {")
            for c in n.children:
                emit(c, depth + 1)
            out.append(pad + "}")
        else:
            out.append(line)

    for n in nodes:
        emit(n, 0)
    return "\n".join(out) + "\n"


KTIME = 46186158000
"""FBX time units per second."""


def _matrix(m: np.ndarray) -> str:
    return ",".join(repr(float(x)) for x in np.asarray(m).T.ravel())      # FBX matrices are column-major


def _translate(x, y, z) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _model(name: str, kind: str, t=(0, 0, 0), extra: str = "") -> str:
    return f'''	Model: "Model::{name}", "{kind}" {{
		Version: 232
		Properties60:  {{
			Property: "RotationOrder", "enum", "",0
			Property: "PreRotation", "Vector3D", "",0,0,0
			Property: "InheritType", "enum", "",1
			Property: "Lcl Translation", "Lcl Translation", "A+",{t[0]},{t[1]},{t[2]}
			Property: "Lcl Rotation", "Lcl Rotation", "A+",0,0,0
			Property: "Lcl Scaling", "Lcl Scaling", "A+",1,1,1
			Property: "Visibility", "Visibility", "A+",1
			Property: "LookAtProperty", "object", ""
		}}
		MultiLayer: 0
		MultiTake: 0
		Shading: Y
		Culling: "CullingOff"
{extra}	}}
'''


def bar_fbx61() -> tuple[str, callable]:
    """(an FBX 6.1 ASCII file, pose(t) -> (V, 3) where its skin should be at time t in jiggle's frame).

    A Y-up bar 2 m long (UnitScaleFactor 100: a unit is a metre), three rings of four vertices at y = 0, 1, 2,
    on two bones: `root` at the origin and `tip` at (0, 1, 0), its child; ring 0 follows the root, ring 2 the
    tip, ring 1 both by half. Its take "bend" (24 fps, 0 to 1 s) moves the root along X with cubic keys
    (`U,s,...,n`), bends the tip 90 degrees about Z with linear keys (`L`), and holds the tip's Y rotation with a
    constant key (`C,n`), the three key layouts of FBX 6."""
    ring = np.array([[-.5, 0, -.5], [.5, 0, -.5], [.5, 0, .5], [-.5, 0, .5]])
    verts = np.concatenate([ring + [0, y, 0] for y in (0.0, 1.0, 2.0)])
    quads = []
    for r in range(2):
        for k in range(4):
            a, b = r * 4 + k, r * 4 + (k + 1) % 4
            quads += [a, b, b + 4, -(a + 4) - 1]
    quads += [0, 3, 2, -2]
    quads += [8, 9, 10, -12]
    w_root = {0: 1.0, 1: 1.0, 2: 1.0, 3: 1.0, 4: .5, 5: .5, 6: .5, 7: .5}
    w_tip = {4: .5, 5: .5, 6: .5, 7: .5, 8: 1.0, 9: 1.0, 10: 1.0, 11: 1.0}
    mesh = f'''		Vertices: {",".join(repr(float(x)) for x in verts.ravel())}
		PolygonVertexIndex: {",".join(map(str, quads))}
		GeometryVersion: 124
		Layer: 0 {{
			Version: 100
		}}
'''

    def cluster(bone, weights, bind):
        return f'''	Deformer: "SubDeformer::Cluster {bone}", "Cluster" {{
		Version: 100
		Properties60:  {{
			Property: "SrcModelReference", "object", ""
		}}
		UserData: "", ""
		Indexes: {",".join(map(str, weights))}
		Weights: {",".join(map(str, weights.values()))}
		Transform: {_matrix(np.linalg.inv(bind))}
		TransformLink: {_matrix(bind)}
	}}
'''
    s = KTIME
    text = f'''; FBX 6.1.0 project file
; ----------------------------------------------------

FBXHeaderExtension:  {{
	FBXHeaderVersion: 1003
	FBXVersion: 6100
	Creator: "FBX SDK/FBX Plugins version 2009.1"
}}
Definitions:  {{
	Version: 100
	Count: 4
}}
Objects:  {{
{_model("bar", "Mesh", extra=mesh)}{_model("root", "Limb")}{_model("tip", "Limb", (0, 1, 0))}	Pose: "Pose::bindPose1", "BindPose" {{
		Type: "BindPose"
		Version: 100
		Properties60:  {{
		}}
		NbPoseNodes: 3
		PoseNode:  {{
			Node: "Model::bar"
			Matrix: {_matrix(np.eye(4))}
		}}
		PoseNode:  {{
			Node: "Model::root"
			Matrix: {_matrix(np.eye(4))}
		}}
		PoseNode:  {{
			Node: "Model::tip"
			Matrix: {_matrix(_translate(0, 1, 0))}
		}}
	}}
	Deformer: "Deformer::Skin bar", "Skin" {{
		Version: 100
		Properties60:  {{
		}}
		Link_DeformAcuracy: 50
	}}
{cluster("root", w_root, np.eye(4))}{cluster("tip", w_tip, _translate(0, 1, 0))}	GlobalSettings:  {{
		Version: 1000
		Properties60:  {{
			Property: "UpAxis", "int", "",1
			Property: "UpAxisSign", "int", "",1
			Property: "FrontAxis", "int", "",2
			Property: "FrontAxisSign", "int", "",1
			Property: "CoordAxis", "int", "",0
			Property: "CoordAxisSign", "int", "",1
			Property: "UnitScaleFactor", "double", "",100
			Property: "TimeMode", "enum", "",11
		}}
	}}
}}

; Object connections
;------------------------------------------------------------------

Connections:  {{
	Connect: "OO", "Model::bar", "Model::Scene"
	Connect: "OO", "Model::root", "Model::Scene"
	Connect: "OO", "Model::tip", "Model::root"
	Connect: "OO", "Deformer::Skin bar", "Model::bar"
	Connect: "OO", "SubDeformer::Cluster root", "Deformer::Skin bar"
	Connect: "OO", "SubDeformer::Cluster tip", "Deformer::Skin bar"
	Connect: "OO", "Model::root", "SubDeformer::Cluster root"
	Connect: "OO", "Model::tip", "SubDeformer::Cluster tip"
}}

Takes:  {{
	Current: "bend"
	Take: "bend" {{
		FileName: "bend.tak"
		LocalTime: 0,{s}
		ReferenceTime: 0,{s}
		Model: "Model::root" {{
			Version: 1.1
			Channel: "Transform" {{
				Channel: "T" {{
					Channel: "X" {{
						Default: 0
						KeyVer: 4005
						KeyCount: 3
						Key: 0,0,U,s,0,0,n,{s // 2},0.25,U,s,0,0,n,{s},0.5,U,s,0,0,n
					}}
					LayerType: 1
				}}
			}}
		}}
		Model: "Model::tip" {{
			Version: 1.1
			Channel: "Transform" {{
				Channel: "R" {{
					Channel: "Y" {{
						Default: 0
						KeyVer: 4005
						KeyCount: 1
						Key: 0,0,C,n
					}}
					Channel: "Z" {{
						Default: 0
						KeyVer: 4005
						KeyCount: 2
						Key: 0,0,L,{s},90,L
					}}
					LayerType: 2
				}}
			}}
		}}
	}}
}}
'''

    def pose(t: float) -> np.ndarray:
        """Where the skin is at time t (keys at 0, 0.5 and 1 s; exact at those times), Z-up metres."""
        tx = np.interp(t, [0, .5, 1], [0, .25, .5])
        a = np.radians(np.interp(t, [0, 1], [0, 90]))
        rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        root = verts + [tx, 0, 0]
        tip = (verts - [0, 1, 0]) @ rot.T + [tx, 1, 0]
        wr = np.array([w_root.get(i, 0.0) for i in range(len(verts))])[:, None]
        y_up = wr * root + (1 - wr) * tip
        return np.column_stack([y_up[:, 0], -y_up[:, 2], y_up[:, 1]])

    return text, pose
