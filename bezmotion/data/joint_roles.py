"""The six characteristic joints of an unknown skeleton, read off its joint names.

Rigs name their joints after a handful of conventions: ``LeftHand`` (Mixamo, CMU, LaFAN1,
MotionBuilder), ``hand_l`` (Unreal), ``hand.L`` (Blender), ``Hand_L`` (Bandai-Namco),
``L_Wrist`` / ``left_wrist`` (SMPL), ``lHand`` (Daz), ``Bip01_L_Hand`` (3ds Max Biped), often
under a namespace or a prefix shared by every joint (``mixamorig:``, ``Character1_``). A
name is split into lower-case words (at separators and at case changes); the words every
joint begins with are dropped; a side word (``left``/``l``, ``right``/``r``) is set aside,
and what remains must be exactly one role's word (a side glued to it, as in Poser/Daz's
lower-case ``lhand`` or ``rfoot``, is split off first):

=========  =====================  =====
role       words                  side
=========  =====================  =====
hips       hips, hip, pelvis      none
head       head                   none
hands      wrist, else hand       left / right
feet       ankle, else foot       left / right
=========  =====================  =====

Exactly, so ``LeftHandIndex1`` or ``HeadTop_End`` never pass for a hand or a head. A skeleton
whose hips no name calls so (``root``, ``body``) gets the joint where the spine and both legs
branch: the deepest one the head and both feet descend from. Where a
skeleton has both a wrist and a hand (SMPL's ``L_Hand`` is the knuckles, a child of the
wrist), the wrist is the joint the rig's two-bone arm ends on; likewise the ankle before a
``foot`` that is the toes.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.geometry.skeleton import ancestors

# Role words by preference (first found wins), and whether the role has a side.
_ROLE_WORDS: Mapping[str, tuple[tuple[str, ...], bool]] = {
    "hips": (("hips", "hip", "pelvis"), False),
    "head": (("head",), False),
    "hand": (("wrist", "hand"), True),
    "foot": (("ankle", "foot"), True),
}
_SIDES = {"left": "left", "l": "left", "right": "right", "r": "right"}

# Word boundaries inside a name: separators, lower→upper ("LeftHand"), an upper-case run before
# a capitalised word ("LHand" → L, Hand), and letters against digits ("Bip01" stays one word).
_WORDS = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|[0-9]+")


def name_words(name: str) -> tuple[str, ...]:
    """``name`` split into lower-case words, its namespace (``ns:`` or ``ns|``) dropped.

    ``"mixamorig:LeftHand"`` → ``("left", "hand")``, ``"hand.L"`` → ``("hand", "l")``,
    ``"Bip01_L_Hand"`` → ``("bip", "01", "l", "hand")``.
    """
    bare = re.split(r"[:|]", name)[-1]
    return tuple(word.lower() for word in _WORDS.findall(bare))


def elided(items: Sequence[object], limit: int = 8) -> str:
    """``items`` joined by commas, those past ``limit`` counted instead of listed
    (``"hip, abdomen, chest, … (165 in all)"``), so that an error line stays readable."""
    shown = ", ".join(map(str, items[:limit]))
    return shown if len(items) <= limit else f"{shown}, … ({len(items)} in all)"


def guess_characteristic_joints(names: Sequence[str], parents: Sequence[int]) -> dict[str, str]:
    """Role → joint name for the six characteristic joints, read off the joint names.

    Args:
      names: the skeleton's joint names.
      parents: each joint's parent index (-1 for the root), in the order of ``names``.
    Returns:
      ``{"hips": …, "head": …, "left_hand": …, "right_hand": …, "left_foot": …, "right_foot": …}``.
    Raises:
      ValueError: a role no joint's name fits, or two joints that fit one role equally (the
        message names them); the head not below the hips; a hand or foot without the two
        ancestors of a two-bone limb.
    """
    words = [name_words(n) for n in names]
    shared = 0  # leading words every joint's name has, a prefix such as "Bip01" or "Character1"
    while all(len(w) > shared + 1 for w in words) and len({w[shared] for w in words}) == 1:
        shared += 1
    found: dict[str, list[tuple[int, int]]] = {}  # role → [(preference, joint)]
    for joint, w in enumerate(words):
        rest = [part for x in w[shared:] if not x.isdigit() for part in _side_split(x)]
        sides = [_SIDES[x] for x in rest if x in _SIDES]
        rest = [x for x in rest if x not in _SIDES]
        if len(rest) != 1 or len(sides) > 1:
            continue
        for role, (role_words, sided) in _ROLE_WORDS.items():
            if rest[0] in role_words and bool(sides) == sided:
                key = f"{sides[0]}_{role}" if sided else role
                found.setdefault(key, []).append((role_words.index(rest[0]), joint))
    mapping = {}
    for role in (*CHARACTERISTIC_JOINTS[1:], CHARACTERISTIC_JOINTS[0]):  # the hips last: they may need the others
        candidates = sorted(found.get(role, []))
        if not candidates and role == "hips" and all(r in mapping for r in ("head", "left_foot", "right_foot")):
            # No name says "hips" (a "root" or "body" joint): where the spine and both legs branch.
            mapping[role] = _branch_point([mapping["head"], mapping["left_foot"], mapping["right_foot"]], parents)
            continue
        if not candidates:
            raise ValueError(f"no joint's name reads as the {role.replace('_', ' ')}")
        best = [j for preference, j in candidates if preference == candidates[0][0]]
        if len(best) > 1 and role == "hips":
            best = _nearest_root(best, parents)
        if len(best) > 1:
            raise ValueError(f"{elided([names[j] for j in best])} all read as the {role.replace('_', ' ')}")
        mapping[role] = best[0]
    _check_hierarchy(mapping, names, parents)
    return {role: names[mapping[role]] for role in CHARACTERISTIC_JOINTS}


def _side_split(word: str) -> tuple[str, ...]:
    """A lower-case word that is a side glued to a role word split in two (Poser/Daz's
    ``lhand``, ``rfoot``; ``lefthand``): ``("l", "hand")``; any other word as it is."""
    for side in sorted(_SIDES, key=len, reverse=True):
        if word.startswith(side) and any(word[len(side):] in role_words for role_words, _ in _ROLE_WORDS.values()):
            return side, word[len(side):]
    return (word,)


def _branch_point(joints: Sequence[int], parents: Sequence[int]) -> int:
    """The deepest joint every one of ``joints`` descends from (or is)."""
    common = set(ancestors(parents, joints[0]))
    for j in joints[1:]:
        common &= set(ancestors(parents, j))
    return max(common, key=lambda j: len(ancestors(parents, j)))


def _nearest_root(joints: Sequence[int], parents: Sequence[int]) -> list[int]:
    """The joints of ``joints`` fewest steps below the root: of two hips, the body's (Daz's
    ``hip`` under a ``figure`` root before a ``hip`` helper below it)."""
    depths = [len(ancestors(parents, j)) for j in joints]
    return [j for j, d in zip(joints, depths) if d == min(depths)]


def _check_hierarchy(mapping: Mapping[str, int], names: Sequence[str], parents: Sequence[int]) -> None:
    """Refuse a guess the rig could not use: the head must descend from the hips, and each hand
    and foot needs two ancestors (its limb's upper and lower bone)."""
    if mapping["hips"] not in ancestors(parents, mapping["head"])[1:]:
        raise ValueError(f"the head {names[mapping['head']]!r} does not descend from the hips {names[mapping['hips']]!r}")
    for role in ("left_hand", "right_hand", "left_foot", "right_foot"):
        if len(ancestors(parents, mapping[role])) < 3:  # itself and two above
            raise ValueError(f"the {role.replace('_', ' ')} {names[mapping[role]]!r} has no two ancestors for a limb")


__all__ = ["elided", "guess_characteristic_joints", "name_words"]
