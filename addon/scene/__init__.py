"""Reading the Blender scene: bounds, appearance, referenced files, render passes, point normals."""
