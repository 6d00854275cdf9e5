"""Regenerate the hand-made legacy models (python3 make_legacy.py).

One small knee-like model written in three legacy document forms, each
reproducing every upgrade rule `osim::legacy` follows:

- `knee_20303.osim` (2.x): joints nested in bodies, `inertia_xx..`,
  `VisibleObject` geometry, `<body>` sockets, `MusclePointSet` paths,
  `pennation_angle`, `Vmax`;
- `knee_30000.osim` (3.x, OpenSim 3.0): joints nested in bodies, GeometryPath,
  BushingForce `body_1`/`body_2` with and without offsets;
- `knee_30501.osim` (4.0 development): JointSet with
  `<connectors><Connector_PhysicalFrame_>` and `location_in_parent` /
  `location_in_child`, markers with connectors.

All three carry: Thelen2003 and Millard2012 muscles with `min_control` 0 and
`max_control` 1 (OpenSim drops both: the muscle's own defaults apply), a muscle
with `min_control` 0.05 (kept), a CoordinateActuator with `min_control` 0
(not a muscle: kept), forces with `isDisabled` true and false, a
CoordinateCouplerConstraint with `isDisabled`, a PrescribedController with
`isDisabled`, markers, conditional and moving path points, wrap objects,
frame offsets that are not round at 6 digits.
"""
import os

HERE = os.path.dirname(os.path.abspath(__file__))


def coord(name, default, rng):
    return f"""<Coordinate name="{name}">
<motion_type>rotational</motion_type>
<default_value>{default}</default_value>
<range>{rng}</range>
<clamped>false</clamped>
<locked>false</locked>
</Coordinate>"""


def pin(name, parent, child, lp, op, lc, oc, coords, form):
    cs = f"<CoordinateSet><objects>{coords}</objects><groups /></CoordinateSet>"
    if form == "30501":
        return f"""<PinJoint name="{name}">
<connectors>
<Connector_PhysicalFrame_ name="parent_body"><connectee_name>../{parent}</connectee_name></Connector_PhysicalFrame_>
<Connector_PhysicalFrame_ name="child_body"><connectee_name>{child}</connectee_name></Connector_PhysicalFrame_>
</connectors>
<location_in_parent>{lp}</location_in_parent>
<orientation_in_parent>{op}</orientation_in_parent>
<location_in_child>{lc}</location_in_child>
<orientation_in_child>{oc}</orientation_in_child>
{cs}
<reverse>false</reverse>
</PinJoint>"""
    return f"""<Joint><PinJoint name="{name}">
<parent_body>{parent}</parent_body>
<location_in_parent>{lp}</location_in_parent>
<orientation_in_parent>{op}</orientation_in_parent>
<location>{lc}</location>
<orientation>{oc}</orientation>
{cs}
<reverse>false</reverse>
</PinJoint></Joint>"""


def custom_knee(form):
    """The knee: a CustomJoint, rotation about z plus a coupled translation."""
    st = """<SpatialTransform>
<TransformAxis name="rotation1"><coordinates>knee_angle</coordinates><axis>0 0 1</axis>
<function><LinearFunction><coefficients>1 0</coefficients></LinearFunction></function></TransformAxis>
<TransformAxis name="rotation2"><coordinates /><axis>0 1 0</axis><function><Constant><value>0</value></Constant></function></TransformAxis>
<TransformAxis name="rotation3"><coordinates /><axis>1 0 0</axis><function><Constant><value>0</value></Constant></function></TransformAxis>
<TransformAxis name="translation1"><coordinates>knee_angle</coordinates><axis>1 0 0</axis>
<function><SimmSpline><x>-2.0944 -1.0472 0 0.5</x><y>-0.0032 0.00179 0.00410 0.0041</y></SimmSpline></function></TransformAxis>
<TransformAxis name="translation2"><coordinates /><axis>0 1 0</axis><function><Constant><value>0</value></Constant></function></TransformAxis>
<TransformAxis name="translation3"><coordinates /><axis>0 0 1</axis><function><Constant><value>0</value></Constant></function></TransformAxis>
</SpatialTransform>"""
    c = coord("knee_angle", "-0.3", "-2.0944 0.17453293")
    cs = f"<CoordinateSet><objects>{c}</objects></CoordinateSet>"
    lp, lc = "0.00123456789 -0.39876543219 0.00012345678", "0 0.0123456789 0"
    if form == "30501":
        return f"""<CustomJoint name="knee">
<connectors>
<Connector_PhysicalFrame_ name="parent_body"><connectee_name>femur</connectee_name></Connector_PhysicalFrame_>
<Connector_PhysicalFrame_ name="child_body"><connectee_name>tibia</connectee_name></Connector_PhysicalFrame_>
</connectors>
<location_in_parent>{lp}</location_in_parent>
<orientation_in_parent>0 0 0.0174532925199</orientation_in_parent>
<location_in_child>{lc}</location_in_child>
<orientation_in_child>0 0 0</orientation_in_child>
{cs}
<reverse>false</reverse>
{st}
</CustomJoint>"""
    return f"""<Joint><CustomJoint name="knee">
<parent_body>femur</parent_body>
<location_in_parent>{lp}</location_in_parent>
<orientation_in_parent>0 0 0.0174532925199</orientation_in_parent>
<location>{lc}</location>
<orientation>0 0 0</orientation>
{cs}
<reverse>false</reverse>
{st}
</CustomJoint></Joint>"""


def geometry(form, mesh):
    if form == "20303":
        return f"""<VisibleObject><geometry_files>{mesh}</geometry_files>
<scale_factors>1 1 1</scale_factors></VisibleObject>"""
    return f"""<VisibleObject><GeometrySet><objects><DisplayGeometry>
<geometry_file>{mesh}</geometry_file><color>1 1 1</color><transform>0 0 0 0 0 0</transform>
<scale_factors>0.5 1 1</scale_factors><display_preference>4</display_preference><opacity>1</opacity>
</DisplayGeometry></objects><groups /></GeometrySet><scale_factors>1 1 2</scale_factors></VisibleObject>"""


def inertia(form, xx, yy, zz):
    if form == "30501":
        return f"<inertia>{xx} {yy} {zz} 0 0 0</inertia>"
    return (f"<inertia_xx>{xx}</inertia_xx><inertia_yy>{yy}</inertia_yy><inertia_zz>{zz}</inertia_zz>"
            "<inertia_xy>0</inertia_xy><inertia_xz>0</inertia_xz><inertia_yz>0</inertia_yz>")


def body(form, name, mass, joint, extra=""):
    return f"""<Body name="{name}">
<mass>{mass}</mass>
<mass_center>0 -0.17 0</mass_center>
{inertia(form, 0.1339, 0.0351, 0.1412)}
{joint}
{geometry(form, name + '.vtp')}
{extra}
</Body>"""


WRAP = """<WrapObjectSet><objects>
<WrapCylinder name="knee_cyl"><xyz_body_rotation>0 0 0</xyz_body_rotation>
<translation>0.00321 -0.40123 0.0</translation><active>true</active><quadrant>-x</quadrant>
<radius>0.025</radius><length>0.1</length></WrapCylinder>
</objects><groups /></WrapObjectSet>"""


def bodies(form):
    hip_c = coord("hip_flexion", "0.2", "-1.2 1.5")
    pat_c = coord("patella_angle", "-0.3", "-2.0944 0.17453293")
    hip = pin("hip", "ground", "femur", "0.0123456789 0.91234567891 -0.0834567891",
              "0 0 0", "0 0.17123456789 0", "0 0 0", hip_c, form)
    pat = pin("patellofemoral", "tibia", "patella", "0.0498765432 -0.0223456789 0.0012345678",
              "0 0 0.1234567891", "0 0 0", "0 0 0", pat_c, form)
    joints = {"femur": hip, "tibia": custom_knee(form), "patella": pat}
    if form == "30501":
        out = [body(form, n, m, "", WRAP if n == "femur" else "")
               for n, m in [("femur", "9.3014"), ("tibia", "3.7075"), ("patella", "0.0862")]]
        return "\n".join(out), "\n".join(joints.values())
    ground = f"""<Body name="ground"><mass>0</mass><mass_center>0 0 0</mass_center>
{inertia(form, 0, 0, 0)}<Joint />{geometry(form, 'floor.vtp')}</Body>"""
    out = [ground] + [body(form, n, m, joints[n], WRAP if n == "femur" else "")
                      for n, m in [("femur", "9.3014"), ("tibia", "3.7075"), ("patella", "0.0862")]]
    return "\n".join(out), ""


def point(form, name, b, loc):
    return f'<PathPoint name="{name}"><location>{loc}</location><body>{b}</body></PathPoint>'


def points(form, muscle, pts, extra=""):
    inner = "".join(point(form, f"{muscle}-P{i + 1}", b, loc) for i, (b, loc) in enumerate(pts)) + extra
    return f"<GeometryPath><PathPointSet><objects>{inner}</objects></PathPointSet></GeometryPath>"


def conditional(form):
    return """<ConditionalPathPoint name="vasti-C"><location>0.033 -0.403 0.0055</location><body>femur</body>
<coordinate>knee_angle</coordinate><range>-2.6 -1.46</range></ConditionalPathPoint>"""


def moving(form):
    return """<MovingPathPoint name="vasti-M"><location>0 0 0</location><body>tibia</body>
<x_coordinate>knee_angle</x_coordinate><x_location><SimmSpline><x>-2.0944 -1.0472 0 0.5</x>
<y>0.0155 0.0325 0.0536 0.0559</y></SimmSpline></x_location>
<y_coordinate>knee_angle</y_coordinate><y_location><SimmSpline><x>-2.0944 -1.0472 0 0.5</x>
<y>0.0234 0.0312 0.0489 0.0495</y></SimmSpline></y_location>
<z_coordinate>knee_angle</z_coordinate><z_location><Constant><value>0.0018</value></Constant></z_location>
</MovingPathPoint>"""


def thelen(form, name, disabled, minc, maxc, pts, extra=""):
    pen = "pennation_angle" if form == "20303" else "pennation_angle_at_optimal"
    return f"""<Thelen2003Muscle name="{name}">
<isDisabled>{disabled}</isDisabled>
<min_control>{minc}</min_control>
<max_control>{maxc}</max_control>
{points(form, name, pts, extra)}
<max_isometric_force>1294</max_isometric_force>
<optimal_fiber_length>0.0840</optimal_fiber_length>
<tendon_slack_length>0.1570</tendon_slack_length>
<{pen}>0.0872664626</{pen}>
<activation_time_constant>0.01</activation_time_constant>
<deactivation_time_constant>0.04</deactivation_time_constant>
<Vmax>7</Vmax>
<Vmax0>5</Vmax0>
<FmaxTendonStrain>0.033</FmaxTendonStrain>
<FmaxMuscleStrain>0.6</FmaxMuscleStrain>
<KshapeActive>0.5</KshapeActive>
<KshapePassive>4</KshapePassive>
<damping>0.05</damping>
<Af>0.3</Af>
<Flen>1.8</Flen>
</Thelen2003Muscle>"""


def millard(form, name, disabled, pts):
    return f"""<Millard2012EquilibriumMuscle name="{name}">
<isDisabled>{disabled}</isDisabled>
<min_control>0</min_control>
<max_control>1</max_control>
{points(form, name, pts)}
<max_isometric_force>2700</max_isometric_force>
<optimal_fiber_length>0.109</optimal_fiber_length>
<tendon_slack_length>0.326</tendon_slack_length>
<pennation_angle_at_optimal>0</pennation_angle_at_optimal>
<max_contraction_velocity>10</max_contraction_velocity>
<default_activation>0.05</default_activation>
<default_fiber_length>0.109</default_fiber_length>
<activation_time_constant>0.01</activation_time_constant>
<deactivation_time_constant>0.04</deactivation_time_constant>
<minimum_activation>0.01</minimum_activation>
</Millard2012EquilibriumMuscle>"""


def bushing(form):
    return """<BushingForce name="knee_bushing">
<isDisabled>false</isDisabled>
<body_1>femur</body_1><body_2>tibia</body_2>
<location_body_1>0 0 0</location_body_1><orientation_body_1>0 0 0</orientation_body_1>
<location_body_2>0.00123456789 0.41234567891 0</location_body_2><orientation_body_2>0 0 0.0123456789</orientation_body_2>
<rotational_stiffness>10 20 30</rotational_stiffness><translational_stiffness>1000 2000 3000</translational_stiffness>
<rotational_damping>0 0 0</rotational_damping><translational_damping>0 0 0</translational_damping>
</BushingForce>"""


def forces(form):
    vasti = [("femur", "0.029 -0.192 0.031"), ("femur", "0.0335 -0.2084 0.0285")]
    hams = [("femur", "-0.0301 -0.1 0.0"), ("tibia", "-0.0301 -0.0419 0.0293")]
    gas = [("femur", "-0.0127 -0.3929 -0.0235"), ("tibia", "-0.0239 -0.2 0.0")]
    out = [
        thelen(form, "vasti", "false", "0", "1", vasti, conditional(form) + moving(form)),
        millard(form, "hams", "true", hams),
        thelen(form, "gastroc", "false", "0.05", "0.9", gas),
        """<CoordinateActuator name="hip_motor"><isDisabled>true</isDisabled><min_control>0</min_control>
<max_control>1</max_control><coordinate>hip_flexion</coordinate><optimal_force>100</optimal_force></CoordinateActuator>""",
    ]
    out.append(bushing(form))
    return "\n".join(out)


def markers(form):
    rows = [("KNEE", "tibia", "0.0027 0.0123456789 0.0456"), ("HIP", "femur", "0 0.17 0.0821")]
    out = []
    for name, b, loc in rows:
        if form == "30501":
            sock = (f'<connectors><Connector_PhysicalFrame_ name="parent_frame">'
                    f"<connectee_name>/bodyset/{b}</connectee_name></Connector_PhysicalFrame_></connectors>")
        else:
            sock = f"<body>{b}</body>"
        out.append(f'<Marker name="{name}">{sock}<location>{loc}</location><fixed>false</fixed></Marker>')
    return "\n".join(out)


def model(form):
    bs, js = bodies(form)
    jointset = f"<JointSet><objects>{js}</objects><groups /></JointSet>" if js else ""
    return f"""<?xml version="1.0" encoding="UTF-8" ?>
<!-- Hand-made legacy test model ({form} form); see make_legacy.py. -->
<OpenSimDocument Version="{form}">
<Model name="knee_{form}">
<length_units>meters</length_units>
<force_units>N</force_units>
<gravity>0 -9.80665 0</gravity>
<BodySet><objects>
{bs}
</objects><groups /></BodySet>
{jointset}
<ConstraintSet><objects>
<CoordinateCouplerConstraint name="patella_coupler">
<isDisabled>false</isDisabled>
<coupled_coordinates_function><LinearFunction><coefficients>1 0</coefficients></LinearFunction></coupled_coordinates_function>
<independent_coordinate_names>knee_angle</independent_coordinate_names>
<dependent_coordinate_name>patella_angle</dependent_coordinate_name>
<scale_factor>1</scale_factor>
</CoordinateCouplerConstraint>
</objects><groups /></ConstraintSet>
<ForceSet><objects>
{forces(form)}
</objects><groups /></ForceSet>
<ControllerSet><objects>
<PrescribedController name="motor_controller"><isDisabled>true</isDisabled>
<actuator_list>hip_motor</actuator_list>
<FunctionSet name="ControlFunctions"><objects><Constant><value>0.5</value></Constant></objects><groups /></FunctionSet>
</PrescribedController>
</objects><groups /></ControllerSet>
<MarkerSet><objects>
{markers(form)}
</objects><groups /></MarkerSet>
</Model>
</OpenSimDocument>
"""


if __name__ == "__main__":
    for form in ["20303", "30000", "30501"]:
        with open(os.path.join(HERE, f"knee_{form}.osim"), "w") as f:
            f.write(model(form))
