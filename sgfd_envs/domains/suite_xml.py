"""dm_control's suite model files read into editable XML trees, and the edits the robot files share."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence

import numpy as np
from dm_control.suite import common


def read_suite_model(filename: str) -> ET.Element:
    """Parse a dm_control suite model XML (e.g. ``"walker.xml"``) into an editable tree.

    :param filename: file name inside ``dm_control/suite``
    """
    return ET.fromstring(common.read_model(filename))


def find_named(root: ET.Element, tag: str, name: str) -> ET.Element:
    """The unique element ``<tag name="name">`` below ``root``.

    :param root: model tree
    :param tag: element tag, e.g. ``"body"`` or ``"geom"``
    :param name: value of its ``name`` attribute
    """
    found = root.findall(f".//{tag}[@name='{name}']")
    if len(found) != 1:
        raise KeyError(f"expected one <{tag} name={name!r}> in the model, found {len(found)}")
    return found[0]


def find_child(root: ET.Element, tag: str) -> ET.Element:
    """The first ``<tag>`` child of ``root`` (e.g. ``"worldbody"``).

    :param root: model tree
    :param tag: element tag
    """
    child = root.find(tag)
    if child is None:
        raise KeyError(f"expected a <{tag}> in the model, found none")
    return child


def get_floats(element: ET.Element, attribute: str) -> np.ndarray:
    """A numeric XML attribute (e.g. ``pos="0 0 1.3"``) as a float array.

    :param element: XML element
    :param attribute: attribute name
    """
    return np.array(element.attrib[attribute].split(), dtype=np.float64)


def set_floats(element: ET.Element, attribute: str, values: Sequence[float] | np.ndarray) -> None:
    """Write a float vector into a numeric XML attribute.

    :param element: XML element
    :param attribute: attribute name
    :param values: the numbers to write
    """
    element.set(attribute, " ".join(f"{value:.6g}" for value in values))


def to_xml_string(root: ET.Element) -> str:
    """Serialise an edited model tree for ``Physics.from_xml_string``.

    :param root: model tree
    """
    return ET.tostring(root, encoding="unicode")
