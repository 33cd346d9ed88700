"""The six characteristic joints read off joint names (bezmotion.data.joint_roles)."""

from __future__ import annotations

import pytest

from bezmotion.assets import DEMO_CLIP
from bezmotion.data import lafan1
from bezmotion.data.bvh import read_bvh
from bezmotion.data.characteristic import SKELETON_MAPS, preset_of
from bezmotion.data.joint_roles import elided, guess_characteristic_joints, name_words

# One body in the bundled clip's hierarchy (root, hips, spine ×2, neck, head, then per side
# shoulder, upper arm, forearm, hand, and upper leg, lower leg, foot, toes), named by each
# convention. Order: as DEMO_CLIP's joints.
_BODY = ("root", "hips", "spine", "chest", "neck", "head",
         "l_shoulder", "l_upper", "l_fore", "l_hand", "r_shoulder", "r_upper", "r_fore", "r_hand",
         "l_thigh", "l_shin", "l_foot", "l_toes", "r_thigh", "r_shin", "r_foot", "r_toes")  # fmt: skip
_CONVENTIONS = {
    "mixamo": ("mixamorig:Reference mixamorig:Hips mixamorig:Spine mixamorig:Spine1 mixamorig:Neck mixamorig:Head "
               "mixamorig:LeftShoulder mixamorig:LeftArm mixamorig:LeftForeArm mixamorig:LeftHand "
               "mixamorig:RightShoulder mixamorig:RightArm mixamorig:RightForeArm mixamorig:RightHand "
               "mixamorig:LeftUpLeg mixamorig:LeftLeg mixamorig:LeftFoot mixamorig:LeftToeBase "
               "mixamorig:RightUpLeg mixamorig:RightLeg mixamorig:RightFoot mixamorig:RightToeBase"),
    "unreal": ("root pelvis spine_01 spine_02 neck_01 head clavicle_l upperarm_l lowerarm_l hand_l "
               "clavicle_r upperarm_r lowerarm_r hand_r thigh_l calf_l foot_l ball_l thigh_r calf_r foot_r ball_r"),
    "blender": ("root hips spine chest neck head shoulder.L upper_arm.L forearm.L hand.L shoulder.R upper_arm.R "
                "forearm.R hand.R thigh.L shin.L foot.L toe.L thigh.R shin.R foot.R toe.R"),
    "daz": ("figure hip abdomen chest neck head lCollar lShldr lForeArm lHand rCollar rShldr rForeArm rHand "
            "lThigh lShin lFoot lToe rThigh rShin rFoot rToe"),
    "daz_lower_case": ("figure hip abdomen chest neck head lcollar lshldr lforearm lhand rcollar rshldr rforearm rhand "
                       "lthigh lshin lfoot ltoe rthigh rshin rfoot rtoe"),
    "biped": ("Bip01 Bip01_Pelvis Bip01_Spine Bip01_Spine1 Bip01_Neck Bip01_Head Bip01_L_Clavicle Bip01_L_UpperArm "
              "Bip01_L_Forearm Bip01_L_Hand Bip01_R_Clavicle Bip01_R_UpperArm Bip01_R_Forearm Bip01_R_Hand "
              "Bip01_L_Thigh Bip01_L_Calf Bip01_L_Foot Bip01_L_Toe0 Bip01_R_Thigh Bip01_R_Calf Bip01_R_Foot Bip01_R_Toe0"),
}  # fmt: skip


def _parents():
    return read_bvh(DEMO_CLIP).skeleton.parents


@pytest.mark.parametrize("convention", sorted(_CONVENTIONS))
def test_each_naming_convention_gives_the_same_six_joints(convention: str):
    names = _CONVENTIONS[convention].split()
    found = guess_characteristic_joints(names, _parents())
    index = {role: names.index(joint) for role, joint in found.items()}
    assert index == {"hips": 1, "head": 5, "left_hand": 9, "right_hand": 13, "left_foot": 16, "right_foot": 20}


def test_the_presets_read_as_their_own_maps():
    assert guess_characteristic_joints(lafan1.JOINT_NAMES, lafan1.PARENTS) == SKELETON_MAPS["lafan1"]
    demo = read_bvh(DEMO_CLIP).skeleton
    assert guess_characteristic_joints(demo.names, demo.parents) == SKELETON_MAPS["bandai_namco"]


def test_hips_no_name_calls_so_are_where_the_spine_and_legs_branch():
    names = _CONVENTIONS["mixamo"].replace("mixamorig:Hips", "mixamorig:Body").split()
    assert guess_characteristic_joints(names, _parents())["hips"] == "mixamorig:Body"
    unnamed = ["Reference", "root", *_CONVENTIONS["unreal"].split()[2:]]  # Unreal's pelvis called "root", under a "Reference"
    assert guess_characteristic_joints(unnamed, _parents())["hips"] == "root"


def test_a_wrist_and_an_ankle_come_before_a_hand_and_a_foot_below_them():
    """SMPL: ``L_Hand`` is the knuckles, a child of ``L_Wrist``; ``L_Foot`` the toes."""
    names = ["Pelvis", "Spine", "Neck", "Head",
             "L_Elbow_up", "L_Elbow", "L_Wrist", "L_Hand", "R_Elbow_up", "R_Elbow", "R_Wrist", "R_Hand",
             "L_Hip", "L_Knee", "L_Ankle", "L_Foot", "R_Hip", "R_Knee", "R_Ankle", "R_Foot"]  # fmt: skip
    parents = [-1, 0, 1, 2, 2, 4, 5, 6, 2, 8, 9, 10, 0, 12, 13, 14, 0, 16, 17, 18]
    assert guess_characteristic_joints(names, parents) == {
        "hips": "Pelvis", "head": "Head", "left_hand": "L_Wrist", "right_hand": "R_Wrist",
        "left_foot": "L_Ankle", "right_foot": "R_Ankle",
    }  # fmt: skip


def test_a_side_glued_to_a_role_word_is_split_off_and_nothing_else_is():
    names = _CONVENTIONS["daz_lower_case"].split()
    assert guess_characteristic_joints(names, _parents())["left_hand"] == "lhand"
    # "lhandindex1" or "rheadtop" are no hand or head: only a side before exactly a role word splits.
    fingers = [n.replace("lcollar", "lhandindex1") for n in names]
    assert guess_characteristic_joints(fingers, _parents())["left_hand"] == "lhand"


def test_a_preset_is_its_whole_hierarchy_not_six_names():
    """A CMU or MotionBuilder file has LaFAN1's six names (Hips, Head, LeftHand …) but not its
    joints between them: it is no LaFAN1 skeleton."""
    assert preset_of(lafan1.JOINT_NAMES, lafan1.PARENTS) == "lafan1"
    demo = read_bvh(DEMO_CLIP).skeleton
    assert preset_of(demo.names, demo.parents) == "bandai_namco"
    cmu = [n.replace("Spine2", "Neck1") for n in lafan1.JOINT_NAMES]
    assert preset_of(cmu, lafan1.PARENTS) is None
    assert preset_of([*lafan1.JOINT_NAMES, "LeftHandIndex1"], [*lafan1.PARENTS, lafan1.JOINT_NAMES.index("LeftHand")]) is None
    reparented = list(lafan1.PARENTS)
    reparented[lafan1.JOINT_NAMES.index("LeftShoulder")] = lafan1.JOINT_NAMES.index("Spine1")
    assert preset_of(lafan1.JOINT_NAMES, reparented) is None


def test_an_error_lists_a_handful_of_joints_and_counts_the_rest():
    assert elided([f"j{i}" for i in range(165)]) == "j0, j1, j2, j3, j4, j5, j6, j7, … (165 in all)"
    assert elided(["a", "b"]) == "a, b"


def test_names_split_into_words():
    assert name_words("mixamorig:LeftHandIndex1") == ("left", "hand", "index", "1")
    assert name_words("hand.L") == ("hand", "l") and name_words("lHand") == ("l", "hand") and name_words("LHand") == ("l", "hand")
    assert name_words("Bip01_L_Hand") == ("bip", "01", "l", "hand") and name_words("HeadTop_End") == ("head", "top", "end")


def test_names_that_do_not_tell_the_six_joints_raise_naming_why():
    names = _CONVENTIONS["mixamo"].split()
    parents = _parents()
    with pytest.raises(ValueError, match="no joint's name reads as the head"):
        guess_characteristic_joints([f"j{i}" for i in range(len(names))], parents)
    with pytest.raises(ValueError, match=r"no joint's name reads as the left hand"):
        guess_characteristic_joints([n.replace("LeftHand", "LeftPaw") for n in names], parents)
    twice = [n.replace("mixamorig:LeftShoulder", "LeftHand") for n in names]  # two left hands, in two namespaces
    with pytest.raises(ValueError, match=r"LeftHand, mixamorig:LeftHand all read as the left hand"):
        guess_characteristic_joints(twice, parents)
    below = list(names)
    below[1], below[3] = "mixamorig:Chest", "mixamorig:Hips"  # the hips below the spine: still above the head
    assert guess_characteristic_joints(below, parents)["hips"] == "mixamorig:Hips"
    swapped = list(names)
    swapped[5], swapped[1] = "mixamorig:Hips", "mixamorig:Head"  # the head the root's child, the hips below it
    with pytest.raises(ValueError, match="the head 'mixamorig:Head' does not descend from the hips 'mixamorig:Hips'"):
        guess_characteristic_joints(swapped, parents)
