"""Small robots the tests build from scratch (no FANUC names anywhere), as MJCF text.

``serial_mjcf``: a four-axis serial arm (vertical base axis, two pitch axes, a roll axis), no
loop, no compensator unless ``balancer`` asks for a spring tendon across the shoulder. Masses
and lengths are of a small heavy-duty arm; every element has its own name, so that nothing
can work by accident through a FANUC default.
"""

from __future__ import annotations

SERIAL_TEXTS = {
    "actuated": "base_yaw shoulder elbow_pitch tool_roll",
    "reflectors": "t1 t2 t3",
    "payload": "hook",
}


def serial_mjcf(texts: dict | None = None, balancer: bool = False, extra: str = "") -> str:
    """The serial arm's MJCF; ``texts`` replaces or adds description texts (a value None drops
    one), ``balancer`` adds a spring tendon ``balancer`` across the shoulder (listed as a
    compensator), ``extra`` is appended inside <mujoco> (e.g. an <equality>)."""
    t = dict(SERIAL_TEXTS)
    if balancer:
        t["compensators"] = "balancer"
    t.update(texts or {})
    custom = "\n".join(f'    <text name="calbench:{k}" data="{v}"/>' for k, v in t.items() if v is not None)
    tendon = (
        """
  <tendon>
    <spatial name="balancer" stiffness="1e6" springlength="0.5">
      <site site="bal_low"/>
      <site site="bal_high"/>
    </spatial>
  </tendon>"""
        if balancer
        else ""
    )
    return f"""<mujoco model="serial4">
  <compiler angle="degree" autolimits="true" inertiafromgeom="false"/>
  <option gravity="0 0 -9.81"/>
  <custom>
{custom}
  </custom>
  <default>
    <geom contype="0" conaffinity="0" rgba="0.7 0.7 0.75 1"/>
    <site size="0.02"/>
  </default>
  <worldbody>
    <body name="pedestal">
      <geom name="pedestal_geom" type="cylinder" size="0.3 0.2" pos="0 0 0.2"/>
      <body name="column" pos="0 0 0.4">
        <joint name="base_yaw" type="hinge" axis="0 0 1" range="-180 180" stiffness="1e6"/>
        <inertial pos="0 0 0.25" mass="200" diaginertia="10 10 8"/>
        <geom name="column_geom" type="box" size="0.2 0.2 0.25" pos="0 0 0.25"/>
        <site name="bal_low" pos="-0.1 0.25 0.9"/>
        <body name="arm" pos="0.15 0 0.55">
          <joint name="shoulder" type="hinge" axis="0 1 0" range="-60 120" stiffness="1e6"/>
          <inertial pos="0.5 0 0" mass="120" diaginertia="2 20 20"/>
          <geom name="arm_geom" type="capsule" fromto="0.1 0 0 0.9 0 0" size="0.09"/>
          <site name="bal_high" pos="0.35 0.25 0"/>
          <body name="lever" pos="1.0 0 0">
            <joint name="elbow_pitch" type="hinge" axis="0 1 0" range="-150 150" stiffness="1e6"/>
            <inertial pos="0.4 0 0" mass="60" diaginertia="1 8 8"/>
            <geom name="lever_geom" type="capsule" fromto="0.1 0 0 0.7 0 0" size="0.07"/>
            <body name="hand" pos="0.8 0 0">
              <joint name="tool_roll" type="hinge" axis="1 0 0" range="-180 180" stiffness="1e6"/>
              <inertial pos="0.1 0 0" mass="20" diaginertia="0.2 0.2 0.2"/>
              <geom name="hand_geom" type="box" size="0.05 0.12 0.12" pos="0.1 0 0"/>
              <site name="hook" pos="0.3 0 -0.1"/>
              <site name="t1" pos="0.15 0.25 0.2"/>
              <site name="t2" pos="0.15 -0.25 0.2"/>
              <site name="t3" pos="0.15 0 -0.3"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>{tendon}
{extra}
</mujoco>
"""


def fourbar_mjcf() -> str:
    """A three-axis arm whose elbow is driven through a NON-parallel four-bar (paper §3.4's
    structure with unequal links): shoulder and drive crank coaxial, upper arm 1.0 m, crank
    0.3 m, coupler rod 0.95 m, anchor 0.35 m behind the knee. Closed at q = 0 with the passive
    knee and rod hinges at 0; elsewhere their angles are no linear map of the motors'."""
    return """<mujoco model="fourbar3">
  <compiler angle="degree" autolimits="true" inertiafromgeom="false"/>
  <option gravity="0 0 -9.81"/>
  <custom>
    <text name="calbench:actuated" data="yaw shoulder drive"/>
    <text name="calbench:loops" data="closure"/>
    <text name="calbench:reflectors" data="p1 p2 p3"/>
    <text name="calbench:payload" data="hook"/>
  </custom>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="foot">
      <geom type="cylinder" size="0.3 0.2" pos="0 0 0.2"/>
      <body name="column" pos="0 0 0.4">
        <joint name="yaw" axis="0 0 1" range="-180 180" stiffness="1e6"/>
        <inertial pos="0 0 0.2" mass="150" diaginertia="6 6 5"/>
        <geom type="box" size="0.2 0.2 0.2" pos="0 0 0.2"/>
        <body name="boom" pos="0 0 0.5">
          <joint name="shoulder" axis="0 1 0" range="-60 90" stiffness="1e6"/>
          <inertial pos="0.5 0 0" mass="80" diaginertia="1 8 8"/>
          <geom type="capsule" fromto="0 0 0 1 0 0" size="0.06"/>
          <body name="dipper" pos="1 0 0">
            <joint name="knee" axis="0 1 0" range="-180 180"/>
            <inertial pos="0.4 0 0" mass="50" diaginertia="0.5 4 4"/>
            <geom type="capsule" fromto="-0.35 0 0 0.8 0 0" size="0.05"/>
            <site name="anchor" pos="-0.35 -0.3 0"/>
            <site name="hook" pos="0.8 0 -0.1"/>
            <site name="p1" pos="0.75 0.2 0.15"/>
            <site name="p2" pos="0.75 -0.2 0.15"/>
            <site name="p3" pos="0.75 0 -0.25"/>
          </body>
        </body>
        <body name="lever" pos="0 -0.3 0.5">
          <joint name="drive" axis="0 1 0" range="-90 90" stiffness="1e6"/>
          <inertial pos="-0.15 0 0" mass="10" diaginertia="0.1 0.2 0.2"/>
          <geom type="capsule" fromto="0 0 0 -0.3 0 0" size="0.04"/>
          <body name="link" pos="-0.3 0 0">
            <joint name="coupler" axis="0 1 0" range="-180 180"/>
            <inertial pos="0.475 0 0" mass="8" diaginertia="0.01 0.6 0.6"/>
            <geom type="capsule" fromto="0 0 0 0.95 0 0" size="0.03"/>
            <site name="link_end" pos="0.95 0 0"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <equality>
    <connect name="closure" site1="link_end" site2="anchor"/>
  </equality>
</mujoco>
"""
