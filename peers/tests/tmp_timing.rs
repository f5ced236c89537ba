mod support;
use peers::*;
use support::*;
use std::time::Instant;
#[test]
fn timing() {
    let mut scene = defocus_scene();
    scene.width = 256; scene.height = 256;
    scene.planes[0].motion = [0.0, 10.0];
    scene.planes[1].motion = [6.0, 0.0];
    scene.shutter_frames = 1.0;
    for spp in [4usize, 16] {
        let samples = scene.render(spp, 1);
        let v = scene.view(spp, &samples);
        let t = Instant::now(); let _ = shirley(&v, &ShirleyParams::default()).unwrap(); println!("shirley 2-scale {spp} spp: {:?}", t.elapsed());
        let t = Instant::now(); let _ = shirley(&v, &ShirleyParams{variant: ShirleyVariant::FourScale, smooth_motion: true}).unwrap(); println!("shirley 4-scale {spp} spp: {:?}", t.elapsed());
        let t = Instant::now(); let _ = vaidyanathan(&v, &VaidyanathanParams::default()).unwrap(); println!("vaidyanathan {spp} spp: {:?}", t.elapsed());
        let t = Instant::now(); let _ = munkberg(&v, &MunkbergParams::default()).unwrap(); println!("munkberg32 {spp} spp: {:?}", t.elapsed());
        let t = Instant::now(); let _ = munkberg(&v, &MunkbergParams::window_44()).unwrap(); println!("munkberg44 {spp} spp: {:?}", t.elapsed());
    }
    let n = 256*256;
    let c = vec![[0.5f32;4]; n]; let d = vec![3.0f32; n];
    let m: Vec<[f32;2]> = (0..n).map(|i| [((i%256) as f32)/16.0, 3.0]).collect();
    let g = GBufferView{width:256,height:256,color:&c,depth:&d,motion:&m};
    let t = Instant::now(); let _ = guertin(&g, &GuertinParams::default()).unwrap(); println!("guertin: {:?}", t.elapsed());
    let t = Instant::now(); let _ = mcguire(&g, &McGuireParams::default()).unwrap(); println!("mcguire: {:?}", t.elapsed());
}
