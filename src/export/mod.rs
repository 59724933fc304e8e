//! Exporters: scenes and forces in formats other tools read. [`vtk`] writes
//! ParaView's XML PolyData (`.vtp`) and `.pvd` collections for sequences.

pub mod vtk;
