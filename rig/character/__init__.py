"""Character: a skinned glTF, any mesh, or a skeleton in; a frozen `Character` out.

Takes a skinned .glb/.gltf (`gltf_character`), an OBJ/PLY/STL/glTF mesh with automatic bone-heat
weights (`mesh_io`, `bone_heat`), or a body generated around a skeleton (`body`), all through
`load.load_character` / `load.body_character`; gives `character.Character`: rest skin, faces,
normals, joints, bind transforms and top-k weights. Writes skinned glTF back (`gltf_write`).
Imports rig.base and rig.motion."""
