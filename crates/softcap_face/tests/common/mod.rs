pub mod face_scene;
