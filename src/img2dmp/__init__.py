"""img2dmp: from a raw image of handwriting to the movement that wrote it.

Implements and extends Pahič, Gams, Ude, Morimoto, "Deep Encoder-Decoder Networks for
Mapping Raw Images to Dynamic Movement Primitives", ICRA 2018.
"""

__version__ = "0.1.0"
