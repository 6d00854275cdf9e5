"""Regenerate the malformed/hostile .osim corpus (python3 make_corpus.py).

Each case is a small mutation of `valid_base.osim` (a correct 4.x model) or a
hand-written hostile input; INDEX.tsv lists file -> expected error fragment.
"""
import os

BASE = """<?xml version="1.0" encoding="UTF-8" ?>
<OpenSimDocument Version="40600">
	<Model name="corpus_base">
		<Ground name="ground" />
		<gravity>0 -9.80665 0</gravity>
		<length_units>meters</length_units>
		<force_units>N</force_units>
		<BodySet name="bodyset">
			<objects>
				<Body name="sacrum">
					<attached_geometry>
						<Mesh name="sacrum_geom">
							<socket_frame>..</socket_frame>
							<mesh_file>sacrum.vtp</mesh_file>
						</Mesh>
					</attached_geometry>
					<mass>2</mass>
					<mass_center>-0.02 -0.02 0</mass_center>
					<inertia>0.002 0.0024 0.0016 0 0 0</inertia>
				</Body>
				<Body name="L5">
					<mass>1.2</mass>
					<mass_center>-0.01 0 0</mass_center>
					<inertia>0.00067 0.00098 0.00045 0 0 0</inertia>
				</Body>
			</objects>
			<groups />
		</BodySet>
		<JointSet name="jointset">
			<objects>
				<WeldJoint name="sacrum_ground">
					<socket_parent_frame>ground_offset</socket_parent_frame>
					<socket_child_frame>sacrum_offset</socket_child_frame>
					<frames>
						<PhysicalOffsetFrame name="ground_offset">
							<socket_parent>/ground</socket_parent>
							<translation>0 1 0</translation>
							<orientation>0 0 0</orientation>
						</PhysicalOffsetFrame>
						<PhysicalOffsetFrame name="sacrum_offset">
							<socket_parent>/bodyset/sacrum</socket_parent>
							<translation>0 0 0</translation>
							<orientation>0 0 0</orientation>
						</PhysicalOffsetFrame>
					</frames>
				</WeldJoint>
				<CustomJoint name="sacrum_L5">
					<socket_parent_frame>sacrum_offset</socket_parent_frame>
					<socket_child_frame>L5_offset</socket_child_frame>
					<coordinates>
						<Coordinate name="sacrum_L5_rz">
							<default_value>0</default_value>
							<range>-0.5 0.5</range>
							<clamped>false</clamped>
							<locked>false</locked>
						</Coordinate>
					</coordinates>
					<frames>
						<PhysicalOffsetFrame name="sacrum_offset">
							<socket_parent>../../../bodyset/sacrum</socket_parent>
							<translation>0 0.0375 0</translation>
							<orientation>0 0 0.1</orientation>
						</PhysicalOffsetFrame>
						<PhysicalOffsetFrame name="L5_offset">
							<socket_parent>../../../bodyset/L5</socket_parent>
							<translation>0 0 0</translation>
							<orientation>0 0 0</orientation>
						</PhysicalOffsetFrame>
					</frames>
					<SpatialTransform>
						<TransformAxis name="rotation1">
							<coordinates></coordinates>
							<axis>1 0 0</axis>
							<Constant name="function"><value>0</value></Constant>
						</TransformAxis>
						<TransformAxis name="rotation2">
							<coordinates></coordinates>
							<axis>0 1 0</axis>
							<Constant name="function"><value>0</value></Constant>
						</TransformAxis>
						<TransformAxis name="rotation3">
							<coordinates>sacrum_L5_rz</coordinates>
							<axis>0 0 1</axis>
							<SimmSpline name="function"><x>-1 0 1</x><y>-1 0 1</y></SimmSpline>
						</TransformAxis>
						<TransformAxis name="translation1">
							<coordinates></coordinates>
							<axis>1 0 0</axis>
							<Constant name="function"><value>0</value></Constant>
						</TransformAxis>
						<TransformAxis name="translation2">
							<coordinates></coordinates>
							<axis>0 1 0</axis>
							<Constant name="function"><value>0</value></Constant>
						</TransformAxis>
						<TransformAxis name="translation3">
							<coordinates></coordinates>
							<axis>0 0 1</axis>
							<Constant name="function"><value>0</value></Constant>
						</TransformAxis>
					</SpatialTransform>
				</CustomJoint>
			</objects>
			<groups />
		</JointSet>
		<ForceSet name="forceset">
			<objects>
				<BushingForce name="bushing_sacrum_L5">
					<socket_frame1>/jointset/sacrum_L5/sacrum_offset</socket_frame1>
					<socket_frame2>/jointset/sacrum_L5/L5_offset</socket_frame2>
					<rotational_stiffness>68.8 291 51</rotational_stiffness>
					<translational_stiffness>149000 1890000 135000</translational_stiffness>
					<rotational_damping>2.3 2.3 2.3</rotational_damping>
					<translational_damping>1000 1000 1000</translational_damping>
				</BushingForce>
			</objects>
			<groups />
		</ForceSet>
		<MarkerSet name="markerset">
			<objects>
				<Marker name="L5_spinous">
					<socket_parent_frame>/bodyset/L5</socket_parent_frame>
					<location>-0.05 0.01 0</location>
					<fixed>false</fixed>
				</Marker>
			</objects>
			<groups />
		</MarkerSet>
	</Model>
</OpenSimDocument>
"""


def sub(old, new, count=1):
    assert BASE.count(old) >= 1, old
    return BASE.replace(old, new, count)


CASES = [
    # (file, content, expected fragment)
    ("truncated.osim", BASE[: len(BASE) // 2], "malformed XML"),
    ("truncated_at_line.osim", BASE[: BASE.index("\n", len(BASE) // 3) + 1], "is not closed (truncated file?)"),
    ("wrong_root.osim", BASE.replace("OpenSimDocument", "SimmDocument"), "root element is <SimmDocument>"),
    ("unknown_version.osim", sub('Version="40600"', 'Version="50000"'), "unknown document Version 50000"),
    ("version_not_integer.osim", sub('Version="40600"', 'Version="4.6"'), "is not an integer"),
    ("missing_version.osim", sub(' Version="40600"', ""), "missing the Version attribute"),
    ("nan_mass.osim", sub("<mass>1.2</mass>", "<mass>NaN</mass>"), "is not finite"),
    ("nonnumeric_location.osim", sub("<location>-0.05 0.01 0</location>", "<location>-0.05 abc 0</location>"), "'abc' is not a number"),
    ("mass_center_two_numbers.osim", sub("<mass_center>-0.01 0 0</mass_center>", "<mass_center>-0.01 0</mass_center>"), "expected 3 numbers, found 2"),
    ("missing_mass.osim", sub("<mass>1.2</mass>", ""), "missing required property <mass>"),
    ("missing_socket_parent.osim", sub("<socket_parent>/bodyset/sacrum</socket_parent>", ""), "missing required property <socket_parent>"),
    ("missing_child_socket.osim", sub("<socket_child_frame>L5_offset</socket_child_frame>", ""), "missing required property <socket_child_frame>"),
    ("duplicate_body.osim", sub('<Body name="L5">', '<Body name="sacrum">'), "duplicate name 'sacrum' in BodySet"),
    ("duplicate_marker.osim", sub("</Marker>", '</Marker><Marker name="L5_spinous"><socket_parent_frame>/bodyset/L5</socket_parent_frame></Marker>'), "duplicate name 'L5_spinous' in MarkerSet"),
    ("dangling_joint_socket.osim", sub("<socket_parent_frame>sacrum_offset</socket_parent_frame>", "<socket_parent_frame>T12_offset</socket_parent_frame>"), "'T12_offset' does not name a frame"),
    ("dangling_offset_parent.osim", sub("<socket_parent>../../../bodyset/L5</socket_parent>", "<socket_parent>../../../bodyset/L4</socket_parent>"), "'../../../bodyset/L4' does not name a frame"),
    ("dangling_marker.osim", sub("<socket_parent_frame>/bodyset/L5</socket_parent_frame>", "<socket_parent_frame>/bodyset/L9</socket_parent_frame>"), "'/bodyset/L9' does not name a frame"),
    ("dangling_bushing.osim", sub("<socket_frame2>/jointset/sacrum_L5/L5_offset</socket_frame2>", "<socket_frame2>/jointset/none/L5_offset</socket_frame2>"), "socket_frame2 '/jointset/none/L5_offset' does not name a frame"),
    ("path_escapes_root.osim", sub("<socket_parent>../../../bodyset/L5</socket_parent>", "<socket_parent>../../../../../bodyset/L5</socket_parent>"), "does not name a frame"),
    ("cyclic_joints.osim", sub("<socket_parent>/ground</socket_parent>", "<socket_parent>/bodyset/L5</socket_parent>"), "cyclic joint graph"),
    ("two_parents.osim", sub("<socket_parent>/bodyset/sacrum</socket_parent>", "<socket_parent>/bodyset/L5</socket_parent>"), "is the child of two joints"),
    ("self_joint.osim", sub("<socket_parent>../../../bodyset/sacrum</socket_parent>", "<socket_parent>../../../bodyset/L5</socket_parent>"), "connects body 'L5' to itself"),
    ("body_without_joint.osim", sub("</Body>\n\t\t\t</objects>", '</Body>\n\t\t\t\t<Body name="L4"><mass>1</mass></Body>\n\t\t\t</objects>'), "body has no joint path to ground"),
    ("entity_bomb.osim", '<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">\n <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">\n]>\n<OpenSimDocument Version="40600"><Model name="&lol3;"/></OpenSimDocument>\n', "DOCTYPE / entity declarations are not allowed"),
    ("external_entity.osim", '<?xml version="1.0"?>\n<!DOCTYPE m [ <!ENTITY x SYSTEM "file:///etc/passwd"> ]>\n<OpenSimDocument Version="40600"><Model name="m">&x;</Model></OpenSimDocument>\n', "DOCTYPE / entity declarations are not allowed"),
    ("undefined_entity.osim", sub("<publications>", "<publications>") if "<publications>" in BASE else sub('<Model name="corpus_base">', '<Model name="corpus_base">\n\t\t<credits>&author;</credits>'), "undefined entity '&author;'"),
    ("mismatched_tags.osim", sub("</mass_center>", "</mass_centre>"), "malformed XML"),
    ("empty.osim", "", "no root element"),
    ("two_models.osim", sub("\t</Model>\n", '\t</Model>\n\t<Model name="second" />\n'), "more than one <Model>"),
    ("no_model.osim", '<?xml version="1.0" encoding="UTF-8" ?>\n<OpenSimDocument Version="40600">\n\t<Body name="x" />\n</OpenSimDocument>\n', "no <Model> element"),
    ("mesh_escape.osim", sub("<mesh_file>sacrum.vtp</mesh_file>", "<mesh_file>../../../../etc/passwd</mesh_file>"), "contains '..'"),
    ("mesh_absolute.osim", sub("<mesh_file>sacrum.vtp</mesh_file>", "<mesh_file>/etc/passwd</mesh_file>"), "is an absolute path"),
    ("negative_mass.osim", sub("<mass>1.2</mass>", "<mass>-1.2</mass>"), "negative mass"),
    ("bad_bool.osim", sub("<clamped>false</clamped>", "<clamped>maybe</clamped>"), "'maybe' is not true/false"),
    ("length_units_mm.osim", sub("<length_units>meters</length_units>", "<length_units>millimeters</length_units>"), "length_units 'millimeters' is not supported"),
    ("force_units_kgf.osim", sub("<force_units>N</force_units>", "<force_units>kgf</force_units>"), "force_units 'kgf' is not supported"),
    ("missing_transform_axis.osim", BASE.replace('<TransformAxis name="translation3">', '<TransformAxis name="translation4">'), 'missing <TransformAxis name="translation3">'),
    ("spline_length_mismatch.osim", sub("<y>-1 0 1</y>", "<y>-1 0</y>"), "<x> has 3 values but <y> has 2"),
    ("inertia_five_numbers.osim", sub("<inertia>0.00067 0.00098 0.00045 0 0 0</inertia>", "<inertia>0.00067 0.00098 0.00045 0 0</inertia>"), "inertia needs 6 numbers"),
    ("infinite_gravity.osim", sub("<gravity>0 -9.80665 0</gravity>", "<gravity>0 -inf 0</gravity>"), "is not finite"),
    ("range_reversed.osim", sub("<range>-0.5 0.5</range>", "<range>0.5 -0.5</range>"), "range min 0.5 > max -0.5"),
    ("axis_unknown_coordinate.osim", sub("<coordinates>sacrum_L5_rz</coordinates>", "<coordinates>sacrum_L5_rx</coordinates>"), "uses coordinate 'sacrum_L5_rx', which the joint does not own"),
    ("deep_nesting.osim", '<OpenSimDocument Version="40600"><Model name="m">' + "<a>" * 400 + "</a>" * 400 + "</Model></OpenSimDocument>", "nested deeper than"),
    ("legacy_joint_without_parent.osim", '<?xml version="1.0" encoding="UTF-8" ?>\n<OpenSimDocument Version="30000">\n\t<Model name="m">\n\t\t<BodySet>\n\t\t\t<objects>\n\t\t\t\t<Body name="ground"><mass>0</mass><Joint /></Body>\n\t\t\t\t<Body name="b">\n\t\t\t\t\t<mass>1</mass>\n\t\t\t\t\t<Joint>\n\t\t\t\t\t\t<PinJoint name="p">\n\t\t\t\t\t\t\t<location_in_parent>0 0 0</location_in_parent>\n\t\t\t\t\t\t</PinJoint>\n\t\t\t\t\t</Joint>\n\t\t\t\t</Body>\n\t\t\t</objects>\n\t\t</BodySet>\n\t</Model>\n</OpenSimDocument>\n', "joint without <parent_body>"),
    ("legacy_nan_location.osim", '<?xml version="1.0" encoding="UTF-8" ?>\n<OpenSimDocument Version="30000">\n\t<Model name="m">\n\t\t<BodySet>\n\t\t\t<objects>\n\t\t\t\t<Body name="ground"><mass>0</mass><Joint /></Body>\n\t\t\t\t<Body name="b">\n\t\t\t\t\t<mass>1</mass>\n\t\t\t\t\t<Joint>\n\t\t\t\t\t\t<WeldJoint name="w">\n\t\t\t\t\t\t\t<parent_body>ground</parent_body>\n\t\t\t\t\t\t\t<location_in_parent>0 nan 0</location_in_parent>\n\t\t\t\t\t\t</WeldJoint>\n\t\t\t\t\t</Joint>\n\t\t\t\t</Body>\n\t\t\t</objects>\n\t\t</BodySet>\n\t</Model>\n</OpenSimDocument>\n', "is not finite"),
]


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, "valid_base.osim"), "w") as f:
        f.write(BASE)
    lines = []
    for name, text, frag in CASES:
        assert text != BASE, name
        with open(os.path.join(here, name), "w") as f:
            f.write(text)
        lines.append(f"{name}\t{frag}")
    # A file that is not UTF-8.
    with open(os.path.join(here, "not_utf8.osim"), "wb") as f:
        f.write(BASE.encode()[:200] + b"\xff\xfe" + BASE.encode()[200:])
    lines.append("not_utf8.osim\tnot valid UTF-8")
    with open(os.path.join(here, "INDEX.tsv"), "w") as f:
        f.write("# file\texpected error fragment (osim-spine info/convert must fail with it)\n")
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
