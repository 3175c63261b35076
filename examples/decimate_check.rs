use std::time::Instant;
use subdfit::mesh::{decimate, Topology};
fn main() {
    let path = std::env::args().nth(1).unwrap();
    let target: usize = std::env::args().nth(2).unwrap().parse().unwrap();
    let t = Instant::now();
    let m = subdfit::io::read_mesh(std::path::Path::new(&path)).unwrap().mesh;
    println!("read {:?} {} tris", t.elapsed(), m.triangles.len());
    let t = Instant::now();
    println!("M: {:?} ({:?})", Topology::of(&m), t.elapsed());
    let t = Instant::now();
    let (d, st) = decimate(&m, target).unwrap();
    println!("decimate {:?} -> {} tris: {:?} {:?}", t.elapsed(), d.triangles.len(), Topology::of(&d), st);
}
