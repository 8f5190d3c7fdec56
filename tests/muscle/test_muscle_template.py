"""Musculoskeletal templates (rig/muscle/template.py): both file forms, round trips, the built-in human
template, and clear errors for bad labels, numbers, keys and hostile or malformed XML."""
from __future__ import annotations

import dataclasses
import importlib.resources

import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.retarget import ROLES
from jiggle.rig.muscle.shell_params import FAT_SHELL, MODES, MUSCLE_SHELL, ShellParams
from jiggle.rig.muscle.template import (
    FAT_DEPTH,
    FAT_JIGGLE,
    MUSCLE_JIGGLE,
    Attachment,
    BoneMusclePair,
    MuscleTemplate,
    Position,
    Template,
    check_labels,
    load_template,
    read_template,
    template_from_toml,
    template_from_xml,
    template_to_toml,
    template_to_xml,
    write_template,
)

FIGURE5 = """<?xml version="1.0"?>
<boneMusclePair>
  <bone>
    <parentJoint>left_upper_arm</parentJoint>
    <childJoint>left_lower_arm</childJoint>
  </bone>
  <muscle pairId="0" type="upper">
    <name>bicepsBrachii</name>
    <origin>
      <parentJoint>chest</parentJoint>
      <position type="absolute"
        x="-0.42" y="0.04" z="-1.82">
      </position>
    </origin>
    <oHinge>
      <parentJoint>left_upper_arm</parentJoint>
    </oHinge>
  </muscle>
  <muscle pairId="0" type="lower">
    <name>tricepsBrachii</name>
  </muscle>
</boneMusclePair>
"""

SMALL_XML = """<?xml version="1.0" encoding="utf-8"?>
<musculoskeletalTemplate name="small">
  <boneMusclePair>
    <bone><parentJoint>left_upper_leg</parentJoint><childJoint>left_lower_leg</childJoint></bone>
    <partition angle="15"/>
    <muscle pairId="3" type="upper" kind="muscle">
      <name>quads</name>
      <insertion>
        <parentJoint>left_lower_leg</parentJoint>
        <position type="relative" x="1.08" y="0.1" z="0"/>
      </insertion>
      <span t0="0.1" t1="0.95"/>
      <sections rim="0.8" bulge="1.1" main="1.2" bulgePosition="0.3"/>
      <shape tone="0.5" nu="2" thicknessMin="0.005"/>
      <jiggle frequency="6"/>
      <shell sticky="0.25" dropOff="0.5" mode="trajectory"/>
    </muscle>
    <muscle pairId="3" type="lower">
      <name>hams</name>
    </muscle>
  </boneMusclePair>
  <boneMusclePair>
    <bone><parentJoint>spine</parentJoint><childJoint>chest</childJoint></bone>
    <muscle type="single" kind="fat">
      <name>belly</name>
      <sector a0="-60" a1="60"/>
      <shape depth="0.03"/>
    </muscle>
    <muscle kind="multi_belly">
      <name>abs</name>
      <origin><parentJoint>hips</parentJoint></origin>
      <shape count="3"/>
    </muscle>
  </boneMusclePair>
</musculoskeletalTemplate>
"""


def small() -> Template:
    return template_from_xml(SMALL_XML, "small.xml")


def muscle_of(t: Template, name: str) -> MuscleTemplate:
    return next(m for _, m in t.muscles() if m.name == name)


# ------------------------------------------------------------------------------- reading and round trips
def test_xml_values_and_defaults():
    t = small()
    assert t.name == "small" and len(t.pairs) == 2
    p = t.pairs[0]
    assert (p.parent, p.child, p.partition_deg) == ("left_upper_leg", "left_lower_leg", 15.0)
    q = muscle_of(t, "quads")
    assert (q.pair_id, q.type, q.kind, q.count) == (3, "upper", "muscle", 1)
    assert q.insertion == Attachment("left_lower_leg", Position("relative", (1.08, 0.1, 0.0)))
    assert q.origin == Attachment() and q.span == (0.1, 0.95) and q.sector is None
    assert (q.rim_scale, q.bulge_scale, q.main_scale, q.bulge_position) == (0.8, 1.1, 1.2, 0.3)
    assert (q.tone, q.nu, q.thickness_min, q.depth) == (0.5, 2.0, 0.005, 0.0)
    # a partial <jiggle> takes the rest from the kind's defaults
    assert q.jiggle == dataclasses.replace(MUSCLE_JIGGLE, frequency_hz=6.0)
    # and a partial <shell> likewise
    assert q.shell == dataclasses.replace(MUSCLE_SHELL, sticky=0.25, drop_off=0.5, mode="trajectory")
    h = muscle_of(t, "hams")
    assert h.jiggle == MUSCLE_JIGGLE and h.span == (0.0, 1.0) and h.tone == 1.0
    belly = muscle_of(t, "belly")
    assert belly.kind == "fat" and belly.jiggle == FAT_JIGGLE and belly.sector == (-60.0, 60.0)
    assert belly.depth == 0.03 and t.pairs[1].partition_deg == 0.0
    abs_ = muscle_of(t, "abs")
    assert (abs_.type, abs_.kind, abs_.count, abs_.pair_id) == ("single", "multi_belly", 3, None)
    assert t.pairs[1].riding(abs_) == ("hips", "spine", "spine", "chest")
    assert t.labels() == {"left_upper_leg", "left_lower_leg", "spine", "chest", "hips"}
    assert isinstance(t.pairs, tuple) and isinstance(p.muscles, tuple)


def test_xml_round_trip():
    t = small()
    u = template_from_xml(template_to_xml(t))
    assert u == t
    assert template_to_xml(u) == template_to_xml(t)


def test_toml_round_trip():
    t = small()
    text = template_to_toml(t)
    u = template_from_toml(text)
    assert u == t
    assert template_to_toml(u) == text


def test_xml_toml_files_equal(tmp_path):
    t = small()
    write_template(t, tmp_path / "a.xml")
    write_template(t, tmp_path / "a.toml")
    a, b = read_template(tmp_path / "a.xml"), read_template(tmp_path / "a.toml")
    assert a == b == t
    assert a.source.endswith("a.xml") and b.source.endswith("a.toml")
    # XML -> TOML -> XML through files
    write_template(b, tmp_path / "c.xml")
    assert read_template(tmp_path / "c.xml") == t
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.toml", "a.xml", "c.xml"]  # no temp files left
    assert (tmp_path / "a.xml").stat().st_mode & 0o777 == 0o644  # not the temporary file's private 0600


def test_built_in_round_trips():
    t = load_template("human")
    assert template_from_xml(template_to_xml(t)) == t
    assert template_from_toml(template_to_toml(t)) == t


def test_figure5_snippet_parses():
    t = template_from_xml(FIGURE5, "fig5.xml")
    assert t.name == "fig5" and len(t.pairs) == 1
    pair = t.pairs[0]
    assert (pair.parent, pair.child) == ("left_upper_arm", "left_lower_arm")
    biceps, triceps = pair.muscles
    assert (biceps.name, biceps.pair_id, biceps.type) == ("bicepsBrachii", 0, "upper")
    assert biceps.origin == Attachment("chest", Position("absolute", (-0.42, 0.04, -1.82)))
    assert biceps.o_hinge == Attachment("left_upper_arm", None)
    assert (triceps.name, triceps.type) == ("tricepsBrachii", "lower")


def test_built_in_human_template():
    t = load_template("human")
    kinds = [m.kind for _, m in t.muscles()]
    assert sum(k != "fat" for k in kinds) >= 16 and kinds.count("fat") >= 1
    assert set(t.labels()) <= set(ROLES)
    names = [m.name for _, m in t.muscles()]
    for part in ("biceps", "triceps", "deltoid", "forearm_flexors", "forearm_extensors", "quadriceps",
                 "hamstrings", "calf", "glute", "pectoral"):
        assert f"left_{part}" in names and f"right_{part}" in names, part
    assert "abdomen" in names and "belly_fat" in names
    assert any(lbl.startswith("left_") for lbl in t.labels()) and any(lbl.startswith("right_") for lbl in t.labels())
    # the two shipped forms are the same template
    folder = importlib.resources.files("jiggle.rig.muscle") / "templates"
    xml = template_from_xml((folder / "human.xml").read_bytes(), "human.xml")
    toml = template_from_toml((folder / "human.toml").read_text(encoding="utf-8"), "human.toml")
    assert xml == toml == t == load_template("human", form=".xml")
    # mirrored muscles mirror: same numbers, opposite z and angles (see the frame notes in human.toml)
    left, right = muscle_of(t, "left_deltoid"), muscle_of(t, "right_deltoid")
    assert left.sector == (-right.sector[1], -right.sector[0])
    assert left.insertion.position.xyz[2] == -right.insertion.position.xyz[2]
    biceps = muscle_of(t, "left_biceps")
    assert biceps.insertion.position.xyz[0] > 1 and biceps.insertion.position.xyz[1] > 0  # past, in front of the elbow
    assert muscle_of(t, "left_triceps").insertion.position.xyz[1] < 0


def test_load_template_errors(tmp_path):
    with pytest.raises(InputError, match="built-in templates are .*human"):
        load_template("elephant")
    with pytest.raises(InputError, match="not found"):
        load_template(tmp_path / "missing.toml")
    (tmp_path / "t.json").write_text("{}")
    with pytest.raises(InputError, match=r"\.xml or \.toml"):
        read_template(tmp_path / "t.json")


# ------------------------------------------------------------------------------- labels
def test_unknown_label_lists_roles():
    bad = SMALL_XML.replace("<parentJoint>hips</parentJoint>", "<parentJoint>pelvis</parentJoint>")
    with pytest.raises(InputError) as e:
        template_from_xml(bad, "bad.xml")
    msg = str(e.value)
    assert "'pelvis'" in msg and "left_upper_arm" in msg and "pair[1].muscle[1].origin.parent_joint" in msg
    assert e.value.line == SMALL_XML.splitlines().index("      <origin><parentJoint>hips</parentJoint></origin>") + 1


def test_check_labels():
    t = small()
    roles = {"left_upper_leg": 4, "left_lower_leg": 5, "spine": 1, "chest": 2, "hips": 0}
    check_labels(t, roles)
    del roles["hips"]
    names = ("Pelvis", "Spine", "Chest", "Neck", "LThigh", "LShin")
    with pytest.raises(InputError) as e:
        check_labels(t, roles, names)
    msg = str(e.value)
    assert "'hips'" in msg and "known labels" in msg
    assert "left_upper_leg (LThigh)" in msg and "chest (Chest)" in msg
    assert e.value.field == "pair[1].muscle[1].origin.parent_joint"


# ------------------------------------------------------------------------------- hostile and malformed XML
BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
]>
<musculoskeletalTemplate name="&lol4;"/>
"""
EXTERNAL = """<?xml version="1.0"?>
<!DOCTYPE t [ <!ENTITY xxe SYSTEM "file:///etc/passwd"> ]>
<musculoskeletalTemplate name="x">&xxe;</musculoskeletalTemplate>
"""
EXTERNAL_DTD = """<?xml version="1.0"?>
<!DOCTYPE musculoskeletalTemplate SYSTEM "http://example.com/evil.dtd">
<musculoskeletalTemplate name="x"/>
"""


@pytest.mark.parametrize("text", [BILLION_LAUGHS, EXTERNAL, EXTERNAL_DTD], ids=["billion_laughs", "xxe", "dtd"])
def test_hostile_xml_refused(tmp_path, text):
    path = tmp_path / "evil.xml"
    path.write_text(text)
    with pytest.raises(InputError) as e:
        read_template(path)
    assert "refused" in str(e.value) and str(path) in str(e.value)
    assert "root:" not in str(e.value)  # /etc/passwd never read into the message


def test_malformed_xml_names_file_and_line(tmp_path):
    path = tmp_path / "broken.xml"
    lines = SMALL_XML.splitlines()
    lines[9] = '        <position type="relative" x="1.08" y="0.1" z="0">'  # unclosed: mismatched tag later
    path.write_text("\n".join(lines))
    with pytest.raises(InputError) as e:
        read_template(path)
    assert e.value.path == str(path) and e.value.line is not None
    assert "not well-formed" in str(e.value) and f"{path}:{e.value.line}:" in str(e.value)
    path.write_text("this is not xml")
    with pytest.raises(InputError, match=r"broken\.xml:1: not well-formed"):
        read_template(path)


def test_wrong_root_and_unknown_elements():
    with pytest.raises(InputError, match="root element is <skeleton>"):
        template_from_xml("<skeleton/>", "x.xml")
    typo = SMALL_XML.replace("<sections ", "<section ")
    with pytest.raises(InputError, match=r"unknown element <section> in <muscle>") as e:
        template_from_xml(typo, "x.xml")
    assert e.value.line == next(i for i, line in enumerate(SMALL_XML.splitlines(), 1) if "<sections " in line)
    typo = SMALL_XML.replace('bulgePosition="0.3"', 'bulgePos="0.3"')
    with pytest.raises(InputError, match="unknown attribute.*bulgePos"):
        template_from_xml(typo, "x.xml")
    twice = SMALL_XML.replace("<name>hams</name>", "<name>hams</name><name>h2</name>")
    with pytest.raises(InputError, match="<name> given twice"):
        template_from_xml(twice, "x.xml")
    with pytest.raises(InputError, match="needs the attribute z"):
        template_from_xml(SMALL_XML.replace(' z="0"/>', "/>"), "x.xml")


# ------------------------------------------------------------------------------- values out of range
@pytest.mark.parametrize("old, new, field, words", [
    ('tone="0.5"', 'tone="1.5"', "pair[0].muscle[0].tone", "expected a number in [0, 1], got 1.5"),
    ('frequency="6"', 'frequency="-2"', "pair[0].muscle[0].jiggle.frequency", "(0, 100] Hz, got -2.0"),
    ('t0="0.1" t1="0.95"', 't0="0.95" t1="0.1"', "pair[0].muscle[0].span", "expected t0 < t1"),
    ('type="upper"', 'type="top"', "pair[0].muscle[0].type", "expected one of upper, lower, single, got 'top'"),
    ('kind="fat"', 'kind="lard"', "pair[1].muscle[0].kind", "expected one of muscle, fat, multi_belly"),
    ('a0="-60" a1="60"', 'a0="60" a1="-60"', "pair[1].muscle[0].sector", "a0 < a1 <= a0 + 360"),
    ('nu="2"', 'nu="two"', "pair[0].muscle[0].nu", "expected a number, got 'two'"),
    ('nu="2"', 'nu="nan"', "pair[0].muscle[0].nu", "expected a number in [0, 100]"),
    ('count="3"', 'count="2.5"', "pair[1].muscle[1].count", "expected an integer"),
    ('<shape depth="0.03"/>', '<shape depth="0.03" count="2"/>', "pair[1].muscle[0].count", "'multi_belly'"),
    ('pairId="3" type="lower"', 'pairId="3" type="upper"', "pair[0].muscle[1].type", "already has an 'upper'"),
    ('<name>hams</name>', '<name>quads</name>', "pair[0].muscle[1].name", "used twice"),
    ('type="relative" x="1.08"', 'type="local" x="1.08"', "pair[0].muscle[0].insertion.position.type",
     "expected one of relative, absolute"),
    ('angle="15"', 'angle="400"', "pair[0].partition", "[-360, 360] degrees"),
])
def test_out_of_range_xml(old, new, field, words):
    assert old in SMALL_XML
    with pytest.raises(InputError) as e:
        template_from_xml(SMALL_XML.replace(old, new, 1), "bad.xml")
    assert e.value.field == field and words in e.value.message, str(e.value)
    assert e.value.path == "bad.xml" and e.value.line is not None
    assert str(e.value).startswith(f"bad.xml:{e.value.line}: {field}: ")


def test_out_of_range_toml_and_keys():
    text = template_to_toml(small())
    with pytest.raises(InputError) as e:
        template_from_toml(text.replace("tone = 0.5", "tone = 1.5"), "t.toml")
    assert str(e.value) == "t.toml: pair[0].muscle[0].tone: expected a number in [0, 1], got 1.5"
    with pytest.raises(InputError, match=r"pair\[0\]\.muscle\[0\]\.jiggle\.frequency: expected a number in \(0, 100\]"):
        template_from_toml(text.replace("frequency = 6.0", "frequency = -6.0"), "t.toml")
    with pytest.raises(InputError, match=r"span: expected t0 < t1"):
        template_from_toml(text.replace("span = [0.1, 0.95]", "span = [0.95, 0.1]"), "t.toml")
    with pytest.raises(InputError, match=r"type: expected one of upper, lower, single, got 'middle'"):
        template_from_toml(text.replace('type = "upper"', 'type = "middle"'), "t.toml")
    with pytest.raises(InputError, match=r"pair\[0\]\.muscle\[0\]\.tonus: unknown key"):
        template_from_toml(text.replace("tone = 0.5", "tonus = 0.5"), "t.toml")
    with pytest.raises(InputError, match=r"jiggle\.freq: unknown key"):
        template_from_toml(text.replace("frequency = 6.0", "freq = 6.0"), "t.toml")
    with pytest.raises(InputError, match=r"tone: expected a number, got '0.5'"):
        template_from_toml(text.replace("tone = 0.5", 'tone = "0.5"'), "t.toml")
    with pytest.raises(InputError, match=r"pair\[0\]\.bone: unknown joint label 'knee'; template labels are roles"):
        template_from_toml(text.replace('"left_lower_leg"]', '"knee"]'), "t.toml")
    with pytest.raises(InputError, match="not valid TOML"):
        template_from_toml("name = ", "t.toml")


def test_programmatic_template_checked_on_write(tmp_path):
    m = MuscleTemplate("m", type="upper")  # half of a pair without a pair id
    t = Template("x", (BoneMusclePair("hips", "spine", 0, (m,)),))
    with pytest.raises(InputError, match="needs a pair id"):
        write_template(t, tmp_path / "x.toml")
    assert not list(tmp_path.iterdir())
    ok = Template("x", [BoneMusclePair("hips", "spine", 0, [dataclasses.replace(m, pair_id=0)])])
    assert ok.pairs[0].muscles[0].jiggle == MUSCLE_JIGGLE
    fat = MuscleTemplate("f", kind="fat")  # kind-dependent defaults fill depth and jiggle
    assert (fat.depth, fat.jiggle) == (FAT_DEPTH, FAT_JIGGLE) and MuscleTemplate("m").depth == 0.0
    assert read_template(write_template(ok, tmp_path / "x.toml")) == ok


# ------------------------------------------------------------------------------- shell deformer defaults
def test_shell_default_by_kind():
    assert FAT_SHELL != MUSCLE_SHELL  # else the kind tests below prove nothing
    assert MuscleTemplate("m").shell == MUSCLE_SHELL
    assert MuscleTemplate("m", kind="multi_belly", count=2).shell == MUSCLE_SHELL
    assert MuscleTemplate("f", kind="fat").shell == FAT_SHELL
    given = ShellParams(sticky=0.5, mode="basic")
    assert MuscleTemplate("f", kind="fat", shell=given).shell is given
    t = small()
    assert muscle_of(t, "hams").shell == MUSCLE_SHELL and muscle_of(t, "belly").shell == FAT_SHELL
    human = load_template("human")
    for _, m in human.muscles():
        assert m.shell == (FAT_SHELL if m.kind == "fat" else MUSCLE_SHELL), m.name
    # a default written out or left to apply gives equal templates
    assert MuscleTemplate("f", kind="fat", shell=FAT_SHELL) == MuscleTemplate("f", kind="fat")


def test_shell_partial_table_fills_from_kind():
    xml = SMALL_XML.replace('<shape depth="0.03"/>', '<shape depth="0.03"/><shell hard="0.8" slippage="2"/>')
    belly = muscle_of(template_from_xml(xml, "x.xml"), "belly")
    assert belly.shell == dataclasses.replace(FAT_SHELL, hard=0.8, slippage=2.0)
    text = template_to_toml(small())
    fat_line = next(line for line in text.splitlines() if line.startswith("shell = ") and "drop_off = 0.75" in line)
    t = template_from_toml(text.replace(fat_line, 'shell = { weight = 0.5, mode = "basic" }'), "t.toml")
    assert muscle_of(t, "belly").shell == dataclasses.replace(FAT_SHELL, weight=0.5, mode="basic")
    assert muscle_of(t, "hams").shell == MUSCLE_SHELL
    # an empty table is the kind's default
    t = template_from_toml(text.replace(fat_line, "shell = {}"), "t.toml")
    assert muscle_of(t, "belly").shell == FAT_SHELL


SHELL_BAD = [
    ("sticky", "1.5", "expected a value in [0, 1], got 1.5"),
    ("sticky", "nan", "expected a value in [0, 1], got nan"),
    ("hard", "-0.1", "expected a value in [0, 1], got -0.1"),
    ("drop_off", "0", "expected a finite value > 0"),
    ("drop_off", "inf", "expected a finite value > 0"),
    ("weight", "2", "expected a value in [0, 1], got 2.0"),
    ("slippage", "-1", "expected a finite value >= 0, got -1.0"),
    ("mode", "wobble", f"expected one of {', '.join(MODES)}, got 'wobble'"),
]


@pytest.mark.parametrize("key, value, words", SHELL_BAD, ids=[f"{k}={v}" for k, v, _ in SHELL_BAD])
def test_shell_bad_value_xml(key, value, words):
    xml_key = "dropOff" if key == "drop_off" else key
    old = '<shell sticky="0.25" dropOff="0.5" mode="trajectory"/>'
    new = f'<shell {xml_key}="{value}"/>'
    with pytest.raises(InputError) as e:
        template_from_xml(SMALL_XML.replace(old, new), "bad.xml")
    field = f"pair[0].muscle[0].shell.{key}"
    line = next(i for i, text in enumerate(SMALL_XML.splitlines(), 1) if "<shell " in text)
    assert e.value.field == field and words in e.value.message, str(e.value)
    assert str(e.value).startswith(f"bad.xml:{line}: {field}: ")


@pytest.mark.parametrize("key, value, words", SHELL_BAD, ids=[f"{k}={v}" for k, v, _ in SHELL_BAD])
def test_shell_bad_value_toml(key, value, words):
    text = template_to_toml(small())
    old = 'shell = { sticky = 0.25, hard = 0.5, drop_off = 0.5, weight = 1.0, slippage = 1.0, mode = "trajectory" }'
    assert old in text
    toml_value = f'"{value}"' if key == "mode" else value
    with pytest.raises(InputError) as e:
        template_from_toml(text.replace(old, f"shell = {{ {key} = {toml_value} }}"), "t.toml")
    assert str(e.value) == f"t.toml: pair[0].muscle[0].shell.{key}: " + e.value.message
    assert words in e.value.message, str(e.value)


def test_shell_wrong_types_and_unknown_keys():
    text = template_to_toml(small())
    old = 'shell = { sticky = 0.25'
    with pytest.raises(InputError, match=r"t\.toml: pair\[0\]\.muscle\[0\]\.shell\.sticky: expected a number, got '0.25'"):
        template_from_toml(text.replace(old, 'shell = { sticky = "0.25"'), "t.toml")
    with pytest.raises(InputError, match=r"shell\.mode: expected a string, got 2"):
        template_from_toml(text.replace('mode = "trajectory"', "mode = 2"), "t.toml")
    with pytest.raises(InputError, match=r"pair\[0\]\.muscle\[0\]\.shell: expected a table"):
        template_from_toml(text.replace(
            'shell = { sticky = 0.25, hard = 0.5, drop_off = 0.5, weight = 1.0, slippage = 1.0, mode = "trajectory" }',
            "shell = 1.0"), "t.toml")
    with pytest.raises(InputError) as e:
        template_from_toml(text.replace(old, "shell = { stiky = 0.25"), "t.toml")
    assert e.value.field == "pair[0].muscle[0].shell.stiky"
    assert "unknown key(s) 'stiky'; expected sticky, hard, drop_off, weight, slippage, mode" in e.value.message
    with pytest.raises(InputError) as e:
        template_from_xml(SMALL_XML.replace('dropOff="0.5"', 'drop_off="0.5"'), "x.xml")
    assert "unknown attribute(s) drop_off of <shell>; expected sticky, hard, dropOff, weight, slippage, mode" in str(e.value)
    assert e.value.field == "pair[0].muscle[0].shell" and e.value.line is not None
    with pytest.raises(InputError, match=r"shell\.sticky: expected a number, got 'soft'"):
        template_from_xml(SMALL_XML.replace('sticky="0.25"', 'sticky="soft"'), "x.xml")
    with pytest.raises(InputError, match="<shell> given twice"):
        template_from_xml(SMALL_XML.replace('<jiggle frequency="6"/>', '<jiggle frequency="6"/><shell/>'), "x.xml")


def test_shell_round_trip(tmp_path):
    shell = ShellParams(sticky=0.125, hard=0.75, drop_off=2.5, weight=0.3, slippage=0.0, mode="basic")
    m = MuscleTemplate("m", kind="fat", shell=shell)
    t = Template("x", (BoneMusclePair("hips", "spine", 0, (m, MuscleTemplate("n"))),))
    for suffix in (".toml", ".xml"):
        u = read_template(write_template(t, tmp_path / f"x{suffix}"))
        assert u == t and u.pairs[0].muscles[0].shell == shell and u.pairs[0].muscles[1].shell == MUSCLE_SHELL
    # TOML -> XML -> TOML through the text forms
    text = template_to_toml(t)
    assert template_to_toml(template_from_xml(template_to_xml(template_from_toml(text)))) == text
    assert 'shell = { sticky = 0.125, hard = 0.75, drop_off = 2.5, weight = 0.3, slippage = 0.0, mode = "basic" }' in text
    assert '<shell sticky="0.125" hard="0.75" dropOff="2.5" weight="0.3" slippage="0.0" mode="basic" />' in template_to_xml(t)


def test_programmatic_shell_checked():
    t = Template("x", (BoneMusclePair("hips", "spine", 0, (MuscleTemplate("m", shell={"sticky": 1.0}),)),))
    with pytest.raises(InputError, match=r"pair\[0\]\.muscle\[0\]\.shell: expected rig\.muscle\.shell_params\.ShellParams, got dict"):
        template_to_toml(t)


# ------------------------------------------------------------------------------- materials
def test_a_part_carries_its_material():
    """A part's jiggle names its material (default its kind's); the springs, damping and density it leaves out are
    the material's to set (Jiggle.from_material), the ones it gives stay; both forms write the material and only the
    values given, and read back equal."""
    t = small()
    q, h, belly = muscle_of(t, "quads"), muscle_of(t, "hams"), muscle_of(t, "belly")
    assert (h.jiggle.material, belly.jiggle.material) == ("muscle", "fat")
    assert h.jiggle.from_material == ("frequency_hz", "damping_ratio", "density")
    assert q.jiggle.frequency_hz == 6.0 and q.jiggle.from_material == ("damping_ratio", "density")
    toml = template_to_toml(t)
    assert 'jiggle = { material = "fat",' in toml and "frequency = 6.0" in toml
    assert toml.count("frequency = ") == 1 + toml.count("spring_frequency = ")
    soft = template_from_toml(toml.replace('jiggle = { material = "muscle", frequency = 6.0',
                                           'jiggle = { material = "E=40kPa,zeta=0.3", frequency = 6.0'), "t.toml")
    assert muscle_of(soft, "quads").jiggle.material == "E=40kPa,zeta=0.3"
    assert template_from_toml(template_to_toml(soft)) == soft
    assert template_from_xml(template_to_xml(soft)) == soft
    with pytest.raises(InputError, match=r"t\.toml: pair\[0\]\.muscle\[0\]\.jiggle\.material: material: expected fat, "
                                         r"muscle or E=\.\.\.,nu=\.\.\.,rho=\.\.\.,zeta=\.\.\., got 'wood'"):
        template_from_toml(toml.replace('material = "muscle", frequency = 6.0', 'material = "wood", frequency = 6.0'),
                           "t.toml")
    with pytest.raises(InputError, match=r"jiggle\.material: material: unknown material key 'G'"):
        template_from_xml(SMALL_XML.replace('<jiggle frequency="6"/>', '<jiggle material="G=3"/>'), "s.xml")


def test_built_in_templates_say_what_sets_their_springs():
    """Both built-in templates leave every part's springs to its material (its kind's): the human's and the
    quadruped's alike (a creature's are then held under the limit on its cycles, sim.bake.setup)."""
    for name in ("human", "quadruped"):
        t = load_template(name)
        assert all(m.jiggle.from_material == ("frequency_hz", "damping_ratio", "density") for _, m in t.muscles())
        assert all(m.jiggle.material == ("fat" if m.kind == "fat" else "muscle") for _, m in t.muscles())
